// CUDA paths (skipped without a GPU): the fused RMS_norm + SiLU kernels
// (forward, and backward under autograd) against the ATen path, and the CUDA
// decoder (inference and training) against the CPU.
#include "flat/model/rms_norm.h"
#include "flat/model/scene_decoder.h"
#include "flat/model/wan_vae.h"
#include "flat/model/weights.h"
#include "test_support.h"

using namespace flat::model;

namespace {

// cuDNN's convs default to TF32: off for exact fp32 comparisons, restored after.
struct NoTf32 {
  bool was = at::globalContext().allowTF32CuDNN();
  NoTf32() { at::globalContext().setAllowTF32CuDNN(false); }
  ~NoTf32() { at::globalContext().setAllowTF32CuDNN(was); }
};

// A small (dim 16) scene decoder on the CPU, and a CUDA copy of its weights.
std::pair<SceneDecoder, SceneDecoder> cpu_and_cuda_decoders() {
  SceneDecoderConfig config;
  config.vae.dim = 16;
  SceneDecoder cpu(config);
  SceneDecoder gpu(config);
  load_state(*gpu, state_tensors(*cpu), {}, "cpu copy");
  gpu->to(torch::kCUDA);
  return {cpu, gpu};
}

}  // namespace

TEST_CASE("CUDA fused RMS_norm + SiLU equals the ATen path", "[model][cuda]") {
  FLAT_REQUIRE_CUDA();
  torch::NoGradGuard no_grad;
  for (auto dtype : {torch::kFloat, torch::kBFloat16}) {
    // Channel counts that are not a multiple of 16 bytes (5; 12 in bf16) or
    // too wide for the packed form (500) take the warp-per-pixel path; the
    // rest use 16-byte packs with 4, 8 or 16 lanes per pixel. Blocks of pixels
    // straddle the two batch entries.
    for (int64_t c : {5, 8, 12, 96, 384, 500}) {
      auto x = torch::randn({2, c, 3, 5, 7}, torch::kCUDA).to(dtype).contiguous(at::MemoryFormat::ChannelsLast3d);
      auto gamma = (torch::rand({c, 1, 1, 1}, torch::kCUDA) + 0.5).to(dtype);
      auto history = torch::randn({2, c, 2, 5, 7}, torch::kCUDA).to(dtype);
      REQUIRE(fused_norm_available(x, gamma));
      auto fused = rms_norm_silu_padded(x, gamma, 2, history, /*fused=*/true);
      auto aten = rms_norm_silu_padded(x, gamma, 2, history, /*fused=*/false);
      INFO("C = " << c << " dtype " << dtype);
      CHECK(fused.is_contiguous(at::MemoryFormat::ChannelsLast3d));
      CHECK(flat::test::rel_error(fused, aten) < (dtype == torch::kFloat ? 1e-5 : 1e-2));
    }
  }
  // The forward of a checkpointed block in training: no autograd, an NCDHW
  // bf16 input and an fp32 gamma (a parameter under autocast) still take the
  // kernel (its result is channels-last; the ATen path's keeps NCDHW).
  auto x = torch::randn({2, 96, 3, 5, 7}, torch::kCUDA).to(torch::kBFloat16);
  auto gamma = torch::rand({96, 1, 1, 1}, torch::kCUDA) + 0.5;
  REQUIRE(fused_norm_available(x, gamma));
  auto fused = rms_norm_silu_padded(x, gamma, 2, {}, /*fused=*/true);
  CHECK(fused.is_contiguous(at::MemoryFormat::ChannelsLast3d));
  CHECK(flat::test::rel_error(fused, rms_norm_silu_padded(x.to(torch::kFloat), gamma, 2, {}, false)) < 1e-2);
  // Wider than the kernel takes: the ATen path serves it.
  auto wide = torch::randn({1, 1000, 2, 3, 3}, torch::kCUDA).contiguous(at::MemoryFormat::ChannelsLast3d);
  CHECK_FALSE(fused_norm_available(wide, torch::ones({1000, 1, 1, 1}, torch::kCUDA)));
}

TEST_CASE("CUDA streamed RMS_norm + SiLU hands on its last frames as history", "[model][cuda]") {
  FLAT_REQUIRE_CUDA();
  torch::NoGradGuard no_grad;
  for (auto dtype : {torch::kFloat, torch::kBFloat16}) {
    for (int64_t T : {1, 2, 5}) {  // T < 2: the history mixes old and new frames
     for (int64_t C : {96, 500}) {   // 16-byte packs, and the warp-per-pixel form
      auto x = torch::randn({2, C, T, 5, 7}, torch::kCUDA).to(dtype).contiguous(at::MemoryFormat::ChannelsLast3d);
      auto gamma = (torch::rand({C, 1, 1, 1}, torch::kCUDA) + 0.5).to(dtype);
      at::Tensor history = torch::randn({2, C, 2, 5, 7}, torch::kCUDA).to(dtype);
      const at::Tensor before = history;
      auto padded = rms_norm_silu_streamed(x, gamma, 2, history);
      INFO("T = " << T << " C = " << C << " dtype " << dtype);
      CHECK(torch::equal(padded, rms_norm_silu_padded(x, gamma, 2, before)));
      CHECK(torch::equal(history, padded.narrow(2, T, 2)));
     }
    }
  }
}

TEST_CASE("CUDA channels-last scene decoder equals the CPU (fp32)", "[model][cuda]") {
  FLAT_REQUIRE_CUDA();
  torch::manual_seed(11);
  const NoTf32 exact;
  auto [cpu, gpu] = cpu_and_cuda_decoders();
  to_channels_last_3d(*gpu);
  torch::NoGradGuard no_grad;
  auto latent = torch::randn({1, 16, 3, 4, 6});
  auto cams = torch::randn({1, 32, 3, 4, 6});
  auto ref = cpu->forward(latent, cams);
  for (bool streaming : {false, true}) {
    auto out = gpu->forward(latent.cuda(), cams.cuda(), streaming).cpu();
    INFO("streaming " << streaming);
    CHECK(flat::test::rel_error(out, ref) < 1e-4);
  }
  // bf16 runs and stays close.
  gpu->to(torch::kBFloat16);
  auto bf = gpu->forward(latent.cuda().to(torch::kBFloat16), cams.cuda().to(torch::kBFloat16)).to(torch::kFloat).cpu();
  CHECK(flat::test::rel_error(bf, ref) < 0.1);
}

TEST_CASE("CUDA fused RMS_norm + SiLU under autograd: output and gradients equal the ATen path's", "[model][cuda]") {
  FLAT_REQUIRE_CUDA();
  torch::manual_seed(3);
  for (auto dtype : {torch::kFloat, torch::kBFloat16}) {
    // 5 and 12 (bf16: not 16 bytes) and 500: the warp-per-pixel form; the rest
    // 16-byte packs with 4, 8 or 16 lanes. An NCDHW input is made channels-last.
    for (int64_t c : {5, 12, 96, 192, 384, 500}) {
      for (bool channels_last : {true, false}) {
        auto x0 = (torch::randn({2, c, 3, 5, 7}) * 2).to(dtype);
        auto gamma0 = torch::rand({c, 1, 1, 1}) + 0.5;  // fp32 like a parameter under autocast
        auto weight = torch::randn({2, c, 5, 5, 7});     // d loss / d output, padded frames included
        // Reference: the ATen path in fp64 on the CPU.
        auto xr = x0.to(torch::kDouble).requires_grad_(true);
        auto gr = gamma0.to(torch::kDouble).requires_grad_(true);
        auto ref = rms_norm_silu_padded(xr, gr, 2, {}, /*fused=*/false);
        (ref * weight.to(torch::kDouble)).sum().backward();

        auto x = x0.cuda();
        if (channels_last) x = x.contiguous(at::MemoryFormat::ChannelsLast3d);
        x.requires_grad_(true);
        auto g = gamma0.cuda().requires_grad_(true);
        auto out = rms_norm_silu_padded(x, g, 2, {}, /*fused=*/true);
        INFO("C = " << c << " dtype " << dtype << " channels-last input " << channels_last);
        REQUIRE(out.grad_fn() != nullptr);
        CHECK(out.grad_fn()->name().find("FusedNormSilu") != std::string::npos);  // the fused node, not ATen's
        (out.to(torch::kFloat) * weight.cuda()).sum().backward();
        const double tol = dtype == torch::kFloat ? 1e-5 : 2e-2;
        CHECK(out.is_contiguous(at::MemoryFormat::ChannelsLast3d));
        CHECK(torch::equal(out.narrow(2, 0, 2).cpu(), torch::zeros({2, c, 2, 5, 7}, out.options().device(torch::kCPU))));
        CHECK(flat::test::rel_error(out, ref) < tol);
        CHECK(x.grad().scalar_type() == dtype);
        CHECK(flat::test::rel_error(x.grad(), xr.grad()) < tol);
        CHECK(g.grad().scalar_type() == torch::kFloat);
        CHECK(flat::test::rel_error(g.grad(), gr.grad()) < tol);
      }
    }
  }
  // Wider than the kernel takes: the ATen node serves it.
  auto wide = torch::randn({1, 1000, 2, 3, 3}, torch::kCUDA).requires_grad_(true);
  auto out = rms_norm_silu_padded(wide, torch::ones({1000, 1, 1, 1}, torch::kCUDA), 1, {}, true);
  CHECK(out.grad_fn()->name().find("FusedNormSilu") == std::string::npos);
}

TEST_CASE("CUDA scene decoder gradients (training path, fused norms) equal the CPU's (fp32)", "[model][cuda]") {
  FLAT_REQUIRE_CUDA();
  torch::manual_seed(12);
  const NoTf32 exact;
  auto [cpu, gpu] = cpu_and_cuda_decoders();
  auto latent = torch::randn({1, 16, 3, 4, 6});
  auto cams = torch::randn({1, 32, 3, 4, 6});
  auto ref = cpu->forward(latent, cams);
  auto weight = torch::randn(ref.sizes());
  (ref * weight).sum().backward();
  auto out = gpu->forward(latent.cuda(), cams.cuda());
  (out * weight.cuda()).sum().backward();
  CHECK(flat::test::rel_error(out.cpu(), ref) < 1e-4);
  const auto cpu_params = cpu->named_parameters(), gpu_params = gpu->named_parameters();
  int compared = 0;
  for (const auto& item : cpu_params) {
    const auto& gcpu = item.value().grad();
    const auto& ggpu = gpu_params[item.key()].grad();
    if (!gcpu.defined()) continue;
    INFO(item.key());
    REQUIRE(ggpu.defined());
    CHECK(flat::test::rel_error(ggpu, gcpu) < 1e-3);
    ++compared;
  }
  CHECK(compared > 50);
}

TEST_CASE("CUDA VAE on one frame (each causal conv's single-frame path) equals the CPU, output and weight gradients",
          "[model][cuda]") {
  // The VAE stage's single-frame part trains through CausalConv3d's last
  // temporal tap only (channels-last on the GPU): the same output and weight
  // gradients as the CPU's, which the CPU tests tie to the padded conv.
  FLAT_REQUIRE_CUDA();
  torch::manual_seed(13);
  const NoTf32 exact;
  WanVAEConfig c;
  c.dim = 8;
  WanVAE cpu(c), gpu(c);
  load_state(*gpu, state_tensors(*cpu), {}, "cpu copy");
  gpu->to(torch::kCUDA);
  to_channels_last_3d(*gpu);
  auto frame = torch::rand({2, 3, 1, 16, 16}) * 2 - 1;
  auto run = [&](WanVAE& vae, const at::Tensor& x) {
    vae->zero_grad();
    auto out = vae->decode(vae->encode(x, /*streaming=*/false), /*streaming=*/false, /*clamp=*/false);
    (out * out).sum().backward();
    std::vector<at::Tensor> g;
    for (const auto& p : vae->parameters()) g.push_back(p.grad().defined() ? p.grad().cpu() : torch::zeros({0}));
    return std::make_pair(out.detach().cpu(), g);
  };
  auto [ref, g_ref] = run(cpu, frame);
  auto [out, g_out] = run(gpu, frame.cuda());
  CHECK(out.sizes() == ref.sizes());
  CHECK(flat::test::rel_error(out, ref) < 1e-4);
  REQUIRE(g_out.size() == g_ref.size());
  double worst = 0;
  size_t compared = 0;
  for (size_t i = 0; i < g_ref.size(); ++i) {
    if (g_ref[i].numel() == 0 || g_ref[i].abs().max().item<double>() == 0) continue;
    REQUIRE(g_out[i].numel() == g_ref[i].numel());
    worst = std::max(worst, flat::test::rel_error(g_out[i], g_ref[i]));
    ++compared;
  }
  INFO("worst weight-gradient error " << worst << " over " << compared << " parameters");
  CHECK(compared > 20);
  CHECK(worst < 1e-3);
}
