// SSIM window and LPIPS (random weights, small images): properties, gradients,
// checkpointed chunks, resizing, and the weights file checks.
#include <cmath>

#include "flat/core/autocast_scope.h"
#include "flat/core/tensor_io.h"
#include "flat/loss/lpips.h"
#include "flat/loss/objective.h"
#include "flat/loss/ssim.h"
#include "test_support.h"

using namespace flat::loss;

namespace {
at::Generator gen(uint64_t seed) { return at::make_generator<at::CPUGeneratorImpl>(seed); }

Lpips seeded_lpips(uint64_t seed) {
  torch::manual_seed(seed);
  return Lpips();
}

flat::TensorMap weights_of(Lpips& net) {
  flat::TensorMap m;
  for (const auto& p : net->named_parameters()) {
    std::string key = p.key();  // features_0.weight -> features.0.weight
    if (key.rfind("features_", 0) == 0) key[8] = '.';
    m[key] = p.value().detach().clone();
  }
  return m;
}

// A double-precision LPIPS net (weights from `seed`), images a and b, per-image
// weights w, and the plain autograd gradient of sum(w * lpips(a, b)) in a.
struct LpipsGradCase {
  Lpips net;
  at::Tensor a, b, w, grad;
};
LpipsGradCase lpips_grad_case(uint64_t seed, int64_t height, int64_t width) {
  LpipsGradCase c{seeded_lpips(seed), {}, {}, {}, {}};
  c.net->to(at::kDouble);
  auto g = gen(seed + 1);
  c.a = at::rand({3, 3, height, width}, g, at::kDouble);
  c.b = at::rand({3, 3, height, width}, g, at::kDouble);
  c.w = at::rand({3}, g, at::kDouble);
  auto x = c.a.clone().requires_grad_(true);
  (c.net->forward(x, c.b) * c.w).sum().backward();
  c.grad = x.grad();
  return c;
}
}  // namespace

TEST_CASE("SSIM Gaussian taps equal the published values", "[loss][ssim]") {
  auto g = gaussian_window_1d(11, 1.5, at::kDouble);
  const double published[] = {0.0010284, 0.0075988, 0.0360008, 0.1093607, 0.2130055, 0.2660117};
  REQUIRE(g.numel() == 11);
  for (int k = 0; k < 6; ++k) {
    CHECK(g[k].item<double>() == Approx(published[k]).margin(5e-8));
    CHECK(g[10 - k].item<double>() == Approx(published[k]).margin(5e-8));  // symmetric
  }
  CHECK(g.sum().item<double>() == Approx(1.0).epsilon(1e-14));
}

TEST_CASE("SSIM: 1 for identical images, symmetric, lower for noise", "[loss][ssim]") {
  auto g = gen(1);
  auto a = at::rand({2, 3, 16, 20}, g, at::kDouble);
  auto b = (a + 0.1 * at::randn({2, 3, 16, 20}, g, at::kDouble)).clamp(0, 1);
  auto same = ssim(a, a);
  CHECK((same - 1).abs().max().item<double>() < 1e-12);
  CHECK(flat::test::rel_error(ssim(a, b), ssim(b, a)) < 1e-12);
  CHECK(ssim(a, b).max().item<double>() < 0.99);
  CHECK(ssim_map(a, b).sizes() == at::IntArrayRef({2, 3, 6, 10}));
  REQUIRE_THROWS_WITH(ssim(a.narrow(2, 0, 10), b.narrow(2, 0, 10)), FLAT_CONTAINS("at least 11x11"));
}

TEST_CASE("LPIPS (random weights): zero for identical images, positive and symmetric", "[loss][lpips]") {
  auto net = seeded_lpips(1);
  auto g = gen(2);
  auto a = at::rand({3, 3, 32, 32}, g), b = at::rand({3, 3, 32, 32}, g);
  auto same = net->forward(a, a);
  CHECK(same.abs().max().item<float>() == 0.f);
  auto ab = net->forward(a, b), ba = net->forward(b, a);
  CHECK(ab.min().item<float>() > 0.f);
  CHECK(flat::test::rel_error(ab, ba) < 1e-6);
  // A small perturbation is closer than an unrelated image.
  auto near = (a + 0.02 * at::randn({3, 3, 32, 32}, g)).clamp(0, 1);
  CHECK((net->forward(a, near) < ab).all().item<bool>());
}

TEST_CASE("LPIPS: chunked, checkpointed gradients equal plain autograd and finite differences", "[loss][lpips]") {
  auto [net, a, b, w, grad] = lpips_grad_case(3, 16, 16);
  auto x2 = a.clone().requires_grad_(true);
  auto y2 = b.clone().requires_grad_(true);
  auto d2 = lpips_distance(net, x2, y2, {.max_size = 0, .chunk = 2});  // chunks of 2: (2, 1)
  CHECK(flat::test::rel_error(d2, net->forward(a, b)) < 1e-12);
  (d2 * w).sum().backward();
  CHECK(flat::test::rel_error(x2.grad(), grad) < 1e-10);
  REQUIRE(y2.grad().defined());
  CHECK(y2.grad().abs().sum().item<double>() > 0);

  // A few entries against central differences.
  const double h = 1e-6;
  for (int64_t idx : {0L, 100L, 517L, 1000L, 2303L}) {
    auto p = a.clone(), m = a.clone();
    p.view(-1)[idx] += h;
    m.view(-1)[idx] -= h;
    double fd = ((net->forward(p, b) * w).sum().item<double>() - (net->forward(m, b) * w).sum().item<double>()) /
                (2 * h);
    CHECK(grad.view(-1)[idx].item<double>() == Approx(fd).epsilon(1e-5).margin(1e-9));
  }
}

TEST_CASE("LPIPS: a target without grad, checkpointed or not, gives the plain value and gradient", "[loss][lpips]") {
  auto [net, a, b, w, grad] = lpips_grad_case(12, 16, 24);
  for (bool checkpoint : {false, true}) {
    for (int64_t chunk : {1, 2, 3}) {
      INFO("checkpoint " << checkpoint << " chunk " << chunk);
      auto x2 = a.clone().requires_grad_(true);
      auto d = lpips_distance(net, x2, b, {.max_size = 0, .chunk = chunk, .checkpoint = checkpoint});
      CHECK(flat::test::rel_error(d, net->forward(a, b)) < 1e-12);
      (d * w).sum().backward();
      CHECK(flat::test::rel_error(x2.grad(), grad) < 1e-10);
    }
  }
}

TEST_CASE("LPIPS bf16: near fp32, one gradient with or without checkpointing; autocast does not leak in",
          "[loss][lpips]") {
  auto net = seeded_lpips(14);
  auto g = gen(15);
  auto a = at::rand({2, 3, 24, 32}, g), b = at::rand({2, 3, 24, 32}, g);
  const auto fp32 = lpips_distance(net, a, b, {.max_size = 0});
  std::vector<at::Tensor> values, grads;
  for (bool checkpoint : {false, true}) {
    auto x = a.clone().requires_grad_(true);
    auto d = lpips_distance(net, x, b, {.max_size = 0, .chunk = 2, .checkpoint = checkpoint, .bf16 = true});
    CHECK(d.scalar_type() == at::kFloat);
    d.sum().backward();
    values.push_back(d.detach());
    grads.push_back(x.grad());
  }
  INFO("fp32 " << fp32 << " bf16 " << values[0]);
  CHECK(flat::test::rel_error(values[0], fp32) < 3e-2);
  CHECK(flat::test::rel_error(values[0], fp32) > 0);  // the convolutions did run in bf16
  CHECK(flat::test::rel_error(values[1], values[0]) < 1e-6);
  CHECK(flat::test::rel_error(grads[1], grads[0]) < 1e-5);
  // The fp32 path stays fp32 inside an enclosing bf16 autocast (as the
  // training step has), in the forward and in the checkpointed recomputation.
  auto x = a.clone().requires_grad_(true);
  at::Tensor under_autocast;
  {
    flat::AutocastScope autocast(true, at::kCPU);
    under_autocast = lpips_distance(net, x, b, {.max_size = 0, .chunk = 1, .checkpoint = true});
  }
  CHECK(flat::test::rel_error(under_autocast, fp32) < 1e-6);
  under_autocast.sum().backward();
  auto y = a.clone().requires_grad_(true);
  lpips_distance(net, y, b, {.max_size = 0, .chunk = 1, .checkpoint = false}).sum().backward();
  CHECK(flat::test::rel_error(x.grad(), y.grad()) < 1e-5);
}

TEST_CASE("LPIPS: large images are resized to the configured size", "[loss][lpips]") {
  auto net = seeded_lpips(5);
  auto g = gen(6);
  auto a = at::rand({1, 3, 32, 48}, g), b = at::rand({1, 3, 32, 48}, g);
  namespace F = torch::nn::functional;
  auto opts = F::InterpolateFuncOptions().size(std::vector<int64_t>{16, 24}).mode(torch::kBilinear)
                  .align_corners(false).antialias(true);
  auto expected = net->forward(F::interpolate(a, opts), F::interpolate(b, opts));
  CHECK(flat::test::rel_error(lpips_distance(net, a, b, {.max_size = 24}), expected) < 1e-6);
  CHECK(flat::test::rel_error(lpips_distance(net, a, b, {.max_size = 48}), net->forward(a, b)) < 1e-6);  // no resize
}

TEST_CASE("LPIPS weights file: round trip, and rejection naming the tensor", "[loss][lpips]") {
  auto dir = flat::test::scratch_dir("loss_lpips_weights");
  auto net = seeded_lpips(7);
  auto tensors = weights_of(net);
  REQUIRE(tensors.size() == lpips_tensor_specs().size());
  const std::string good = (dir / "lpips_vgg.safetensors").string();
  flat::save_safetensors(good, tensors);
  check_lpips_file(good);
  auto other = seeded_lpips(8);
  other->load(good);
  auto g = gen(9);
  auto a = at::rand({2, 3, 16, 16}, g), b = at::rand({2, 3, 16, 16}, g);
  CHECK(flat::test::rel_error(other->forward(a, b), net->forward(a, b)) < 1e-7);

  auto missing = tensors;
  missing.erase("features.12.bias");
  const std::string missing_file = (dir / "missing.safetensors").string();
  flat::save_safetensors(missing_file, missing);
  REQUIRE_THROWS_WITH(Lpips()->load(missing_file), FLAT_CONTAINS("features.12.bias"));

  auto misshaped = tensors;
  misshaped["lin3.weight"] = at::zeros({1, 256, 1, 1});
  const std::string misshaped_file = (dir / "misshaped.safetensors").string();
  flat::save_safetensors(misshaped_file, misshaped);
  REQUIRE_THROWS_WITH(check_lpips_file(misshaped_file), FLAT_CONTAINS("lin3.weight"));
  REQUIRE_THROWS_WITH(check_lpips_file(misshaped_file), FLAT_CONTAINS("(1,512,1,1)"));

  REQUIRE_THROWS_WITH(check_lpips_file((dir / "nope.safetensors").string()), FLAT_CONTAINS("not found"));
}

TEST_CASE("objective refuses to start without LPIPS weights when lambda_perc > 0", "[loss][objective]") {
  LossConfig cfg;
  cfg.lpips_weights = "/nonexistent/lpips_vgg.safetensors";
  REQUIRE_THROWS_WITH(Objective(cfg), FLAT_CONTAINS("/nonexistent/lpips_vgg.safetensors"));
  cfg.lpips_weights = "";
  REQUIRE_THROWS_WITH(Objective(cfg), FLAT_CONTAINS("LPIPS"));
  cfg.lambda_perc = 0;
  CHECK_NOTHROW(Objective(cfg));
}

TEST_CASE("objective: lpips_precision auto follows a bf16 run on CUDA only; the lpips_* keys reach LPIPS",
          "[loss][objective]") {
  auto dir = flat::test::scratch_dir("loss_objective_precision");
  auto net = seeded_lpips(16);
  LossConfig cfg;
  cfg.lpips_weights = (dir / "lpips.safetensors").string();
  flat::save_safetensors(cfg.lpips_weights, weights_of(net));
  cfg.lpips_chunk = 17;
  cfg.lpips_checkpoint = false;
  cfg.lpips_max_size = 320;
  const auto o = Objective(cfg, at::kCPU, /*bf16_run=*/true).lpips_options();
  CHECK(o.chunk == 17);
  CHECK(!o.checkpoint);
  CHECK(o.max_size == 320);
  CHECK(!o.bf16);  // auto: fp32 on the CPU even in a bf16 run
  cfg.lpips_precision = "bf16";
  CHECK(Objective(cfg, at::kCPU, false).lpips_options().bf16);
  cfg.lpips_precision = "fp32";
  CHECK(!Objective(cfg, at::kCPU, true).lpips_options().bf16);
  REQUIRE_THROWS_WITH(flat::config::parse<LossConfig>("lpips_precision: fp16\n", "loss.yaml"),
                      FLAT_CONTAINS("lpips_precision"));
}

TEST_CASE("objective: weighted sum of named terms", "[loss][objective]") {
  auto dir = flat::test::scratch_dir("loss_objective");
  auto net = seeded_lpips(10);
  const std::string file = (dir / "lpips.safetensors").string();
  flat::save_safetensors(file, weights_of(net));
  LossConfig cfg;
  cfg.lpips_weights = file;
  cfg.lambda_normal_consistency = 0.05;
  cfg.lambda_distortion = 0.1;
  Objective objective(cfg);

  auto g = gen(11);
  const int64_t V = 2, H = 16, W = 16;
  LossInputs in;
  in.rgb = at::rand({V, 3, H, W}, g).requires_grad_(true);
  in.target_rgb = at::rand({V, 3, H, W}, g);
  in.alpha = at::rand({V, 1, H, W}, g);
  in.depth = (1 + at::rand({V, 1, H, W}, g)).requires_grad_(true);
  in.target_depth = 1 + at::rand({V, 1, H, W}, g);
  in.normal = at::randn({V, 3, H, W}, g).requires_grad_(true);
  in.target_normal = at::randn({V, 3, H, W}, g);
  in.opacities = at::rand({100}, g).requires_grad_(true);
  in.intrinsics = at::tensor({0.8f, 0.8f, 0.5f, 0.5f}).repeat({V, 1});
  in.distortion = at::rand({V, 1, H, W}, g);
  auto r = objective(in);
  for (const char* k : {"rgb", "lpips", "depth", "normal", "opacity", "normal_consistency", "distortion", "total"})
    CHECK(r.terms.count(k) == 1);
  double expected = 1.0 * r.terms["rgb"].item<double>() + 0.5 * r.terms["lpips"].item<double>() +
                    0.01 * r.terms["depth"].item<double>() + 0.01 * r.terms["normal"].item<double>() +
                    0.001 * r.terms["opacity"].item<double>() +
                    0.05 * r.terms["normal_consistency"].item<double>() + 0.1 * r.terms["distortion"].item<double>();
  CHECK(r.total.item<double>() == Approx(expected).epsilon(1e-6));
  r.total.backward();
  for (const auto& t : {in.rgb, in.depth, in.normal, in.opacities}) CHECK(t.grad().abs().sum().item<float>() > 0);

  LossInputs partial;
  partial.rgb = in.rgb.detach();
  partial.target_rgb = in.target_rgb;
  REQUIRE_THROWS_WITH(objective(partial), FLAT_CONTAINS("'depth'"));
}

TEST_CASE("loss config: YAML with paper defaults, validated", "[loss][objective]") {
  auto cfg = flat::config::parse<LossConfig>("lambda_perc: 0\nlpips_max_size: 256\n", "loss.yaml");
  CHECK(cfg.lambda_rgb == 1.0);
  CHECK(cfg.lambda_depth == 0.01);
  CHECK(cfg.lambda_normal == 0.01);
  CHECK(cfg.lambda_opacity == 0.001);
  CHECK(cfg.lambda_perc == 0.0);
  CHECK(cfg.lpips_max_size == 256);
  REQUIRE_THROWS_WITH(flat::config::parse<LossConfig>("lambda_rgb: -1\n", "loss.yaml"), FLAT_CONTAINS("lambda_rgb"));
  REQUIRE_THROWS_WITH(flat::config::parse<LossConfig>("lambda_typo: 1\n", "loss.yaml"), FLAT_CONTAINS("lambda_typo"));
}
