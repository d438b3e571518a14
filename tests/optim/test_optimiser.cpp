// AdamW against a plain double-precision reference of its update rule, the
// learning-rate schedule against hand values, and the optimiser state's
// round trip (the basis of exact resume); and that a step reaches caches
// keyed on weight versions.
#include <cmath>

#include "flat/core/error.h"
#include "flat/model/resample.h"
#include "flat/optim/adamw.h"
#include "test_support.h"

using namespace flat::optim;

namespace {

// One AdamW step on doubles, written from the algorithm (Loshchilov & Hutter).
void reference_step(std::vector<double>& p, std::vector<double>& m, std::vector<double>& v, const std::vector<double>& g,
                    int t, double lr, const AdamWOptions& o) {
  for (size_t i = 0; i < p.size(); ++i) {
    p[i] -= lr * o.weight_decay * p[i];
    m[i] = o.beta1 * m[i] + (1 - o.beta1) * g[i];
    v[i] = o.beta2 * v[i] + (1 - o.beta2) * g[i] * g[i];
    const double mh = m[i] / (1 - std::pow(o.beta1, t)), vh = v[i] / (1 - std::pow(o.beta2, t));
    p[i] -= lr * mh / (std::sqrt(vh) + o.eps);
  }
}

std::vector<double> values(const at::Tensor& t) {
  auto c = t.detach().to(at::kDouble).contiguous();
  return std::vector<double>(c.data_ptr<double>(), c.data_ptr<double>() + c.numel());
}

}  // namespace

TEST_CASE("AdamW equals the reference update rule over several steps", "[optim]") {
  AdamWOptions o;
  o.beta2 = 0.99;
  o.weight_decay = 0.05;
  auto gen = at::make_generator<at::CPUGeneratorImpl>(5);
  auto w = at::randn({4, 3}, gen, at::kDouble).requires_grad_(true);
  AdamW opt({{"w", w}}, o);
  std::vector<double> p = values(w), m(p.size(), 0), v(p.size(), 0);
  const double lrs[] = {0.1, 0.05, 0.02, 0.2};
  for (int t = 1; t <= 4; ++t) {
    auto g = at::randn({4, 3}, gen, at::kDouble);
    w.mutable_grad() = g.clone();
    opt.step(lrs[t - 1]);
    reference_step(p, m, v, values(g), t, lrs[t - 1], o);
    const auto got = values(w);
    for (size_t i = 0; i < p.size(); ++i) REQUIRE(got[i] == Approx(p[i]).epsilon(1e-12));
  }
  CHECK(opt.state().at("step.w").item<double>() == 4.0);
}

TEST_CASE("AdamW leaves parameters without a gradient alone", "[optim]") {
  auto a = at::ones({3}, at::kDouble).requires_grad_(true), b = at::ones({2}, at::kDouble).requires_grad_(true);
  AdamW opt({{"a", a}, {"b", b}}, {});
  a.mutable_grad() = at::ones({3}, at::kDouble);
  opt.step(0.1);
  CHECK(b.eq(1).all().item<bool>());
  CHECK(a.lt(1).all().item<bool>());
  CHECK(opt.state().count("exp_avg.b") == 0);
}

TEST_CASE("AdamW state round trip continues exactly; bad state is refused by name", "[optim]") {
  auto gen = at::make_generator<at::CPUGeneratorImpl>(9);
  auto w1 = at::randn({5}, gen).requires_grad_(true);
  auto w2 = w1.detach().clone().requires_grad_(true);
  AdamW a({{"w", w1}}, {}), b({{"w", w2}}, {});
  std::vector<at::Tensor> grads;
  for (int i = 0; i < 6; ++i) grads.push_back(at::randn({5}, gen));
  for (int i = 0; i < 3; ++i) {
    w1.mutable_grad() = grads[size_t(i)].clone();
    a.step(0.01);
  }
  // b takes a's weights and state, then both continue.
  {
    at::NoGradGuard ng;
    w2.copy_(w1);
  }
  b.load_state(a.state(), "test");
  for (int i = 3; i < 6; ++i) {
    w1.mutable_grad() = grads[size_t(i)].clone();
    w2.mutable_grad() = grads[size_t(i)].clone();
    a.step(0.01);
    b.step(0.01);
  }
  CHECK(at::equal(w1, w2));
  auto bad = a.state();
  bad["exp_avg.w"] = at::zeros({6});
  REQUIRE_THROWS_WITH(b.load_state(bad, "ckpt/optimizer.safetensors"), FLAT_CONTAINS("exp_avg.w"));
  auto extra = a.state();
  extra["exp_avg.ghost"] = at::zeros({1});
  REQUIRE_THROWS_WITH(b.load_state(extra, "ckpt/optimizer.safetensors"), FLAT_CONTAINS("ghost"));
  CHECK(a.state_bytes() == 2 * 5 * 4 + 4);
}

TEST_CASE("AdamW on CUDA (fused and op by op) equals the CPU update", "[optim][cuda]") {
  FLAT_REQUIRE_CUDA();
  auto gen = at::make_generator<at::CPUGeneratorImpl>(21);
  // A conv weight (5-D), the same laid out channels-last, a bias, a scalar.
  std::vector<at::Tensor> init = {at::randn({8, 4, 3, 3, 3}, gen), at::randn({8, 4, 3, 3, 3}, gen), at::randn({8}, gen),
                                  at::randn({}, gen)};
  for (bool fused : {true, false}) {
    std::vector<std::pair<std::string, at::Tensor>> cpu, gpu;
    for (size_t i = 0; i < init.size(); ++i) {
      cpu.push_back({"p" + std::to_string(i), init[i].clone().requires_grad_(true)});
      auto g = init[i].cuda();
      if (i == 1) g = g.contiguous(at::MemoryFormat::ChannelsLast3d);
      gpu.push_back({"p" + std::to_string(i), g.detach().requires_grad_(true)});
    }
    AdamWOptions o;
    o.fused = fused;
    AdamW a(cpu, o), b(gpu, o);
    for (int t = 0; t < 3; ++t) {
      for (size_t i = 0; i < init.size(); ++i) {
        auto grad = at::randn(init[i].sizes(), gen);
        cpu[i].second.mutable_grad() = grad.clone();
        gpu[i].second.mutable_grad() = i == 1 ? grad.cuda().contiguous(at::MemoryFormat::ChannelsLast3d) : grad.cuda();
      }
      a.step(1e-2);
      b.step(1e-2);
    }
    for (size_t i = 0; i < init.size(); ++i) {
      INFO("fused " << fused << ", parameter " << i);
      CHECK(at::isfinite(gpu[i].second).all().item<bool>());
      CHECK(flat::test::rel_error(gpu[i].second, cpu[i].second) < 1e-5);
    }
  }
}

namespace {

// A sub-pixel upsample, its no-grad output cached after one call, then
// stepped by AdamW on `device` (fused or op by op): its next no-grad output
// must be that of a fresh module holding the stepped weights. A step that
// leaves the version counters alone (ATen's _fused_adamw_ does) keeps the
// cached filters of the first call: the trainer's validation then decodes
// with stale upsamples.
void check_upsample_follows_step(const at::Device& device, bool fused) {
  using flat::model::Resample;
  using flat::model::ResampleMode;
  torch::manual_seed(8);
  Resample r(8, ResampleMode::upsample2d);
  r->to(device);
  REQUIRE(r->subpixel_upsample());
  const auto x = torch::randn({1, 8, 2, 5, 4}).to(device);
  at::Tensor first;
  {
    torch::NoGradGuard no_grad;
    first = r->forward(x);  // builds the filter cache
  }
  const auto versions_before = std::make_pair(r->conv_weight._version(), r->conv_bias._version());
  AdamWOptions o;
  o.fused = fused;
  AdamW adam(r->named_parameters().pairs(), o);
  for (auto& p : r->parameters()) p.mutable_grad() = torch::randn_like(p);
  adam.step(5e-2);
  CHECK(r->conv_weight._version() != versions_before.first);
  CHECK(r->conv_bias._version() != versions_before.second);

  Resample fresh(8, ResampleMode::upsample2d);
  fresh->to(device);
  {
    torch::NoGradGuard no_grad;
    fresh->conv_weight.copy_(r->conv_weight);
    fresh->conv_bias.copy_(r->conv_bias);
    const auto after = r->forward(x), expected = fresh->forward(x);
    INFO("device " << device << ", fused " << fused);
    CHECK(flat::test::rel_error(after, expected) < 1e-6);
    CHECK(flat::test::rel_error(after, first) > 1e-3);  // the step did change the output
  }
}

}  // namespace

TEST_CASE("AdamW's step reaches caches keyed on weight versions (sub-pixel upsample filters)", "[optim]") {
  check_upsample_follows_step(at::kCPU, true);
  check_upsample_follows_step(at::kCPU, false);
}

TEST_CASE("AdamW's fused CUDA step reaches caches keyed on weight versions", "[optim][cuda]") {
  FLAT_REQUIRE_CUDA();
  check_upsample_follows_step(at::Device(at::kCUDA, 0), true);
  check_upsample_follows_step(at::Device(at::kCUDA, 0), false);
}
