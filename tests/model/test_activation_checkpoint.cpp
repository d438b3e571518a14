// Activation checkpointing: the same outputs and gradients as the plain
// forward and backward, for the decoder's blocks and for a toy block.
#include <cmath>

#include "flat/model/activation_checkpoint.h"
#include "flat/model/scene_decoder.h"
#include "flat/primitives/head_channels.h"
#include "test_support.h"

using namespace flat;

TEST_CASE("checkpointed block: same output and gradients; the block runs again in the backward",
          "[model][checkpoint]") {
  torch::manual_seed(0);
  auto w = torch::randn({8, 8}, torch::requires_grad());
  auto x = torch::randn({4, 8}, torch::requires_grad());
  int calls = 0;
  auto block = [&](const at::Tensor& h) {
    ++calls;
    return torch::tanh(h.matmul(w)).matmul(w);
  };
  auto y0 = block(x);
  y0.square().sum().backward();
  auto gw0 = w.grad().clone(), gx0 = x.grad().clone();
  w.mutable_grad() = at::Tensor();
  x.mutable_grad() = at::Tensor();
  calls = 0;
  auto y1 = model::checkpointed(block, x);
  CHECK(calls == 1);
  CHECK(at::equal(y0, y1));
  y1.square().sum().backward();
  CHECK(calls == 2);  // recomputed once in the backward
  CHECK(at::equal(gw0, w.grad()));
  CHECK(at::equal(gx0, x.grad()));
  // Without grad mode (inference) it is the plain call.
  torch::NoGradGuard no_grad;
  calls = 0;
  model::checkpointed(block, x);
  CHECK(calls == 1);
}

TEST_CASE("scene decoder with activation checkpointing: identical gradients", "[model][checkpoint]") {
  model::SceneDecoderConfig cfg;
  cfg.vae.dim = 8;
  torch::manual_seed(5);
  model::SceneDecoder plain(cfg, primitives::triangle_channels("ray_centred"));
  cfg.activation_checkpointing = true;
  model::SceneDecoder ckpt(cfg, primitives::triangle_channels("ray_centred"));
  {
    torch::NoGradGuard no_grad;
    auto src = plain->named_parameters();
    for (auto& p : ckpt->named_parameters()) p.value().copy_(src[p.key()]);
    // Non-zero adapter and heads, so that every parameter gets a gradient.
    for (auto& p : ckpt->named_parameters())
      if (p.key().rfind("adapter.", 0) == 0) p.value().normal_(0, 0.05);
    for (auto& p : plain->named_parameters()) p.value().copy_(ckpt->named_parameters()[p.key()]);
  }
  CHECK(ckpt->decoder->activation_checkpointing());
  auto latent = torch::randn({1, 16, 2, 4, 6});
  auto cams = torch::randn({1, 32, 2, 4, 6});
  auto weights = torch::randn({1, 12, 5, 16, 24});
  auto loss_of = [&](model::SceneDecoder& m) { return (m->forward(latent, cams) * weights).sum(); };
  // The checkpointed blocks run their first forward without grad mode, where
  // the CPU convolution library may pick other kernels: bit-identical on the
  // 2-core CI machine, 6e-7 apart in the loss and up to 1.4e-6 in gradients
  // on the GPU machine's 16 cores. A wrong recompute differs by O(1).
  auto l0 = loss_of(plain), l1 = loss_of(ckpt);
  CHECK(std::abs(l0.item<double>() - l1.item<double>()) <= 1e-6 * std::abs(l0.item<double>()));
  l0.backward();
  l1.backward();
  auto g0 = plain->named_parameters(), g1 = ckpt->named_parameters();
  int64_t compared = 0, with_grad = 0;
  for (auto& p : g0) {
    const auto& a = p.value().grad();
    const auto& b = g1[p.key()].grad();
    REQUIRE(a.defined() == b.defined());
    if (!a.defined()) continue;
    ++with_grad;
    CHECK(test::rel_error(b, a) < 1e-5);
    compared += at::equal(a, b) ? 1 : 0;
  }
  CHECK(with_grad > 30);
  std::cout << "activation checkpointing: " << compared << " of " << with_grad
            << " parameter gradients bit-identical, the rest within 1e-5\n";
}
