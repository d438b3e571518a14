// PSNR and SSIM against independently computed values; normal accuracy; LPIPS
// metric wrapper.
#include <cmath>
#include <vector>

#include "flat/eval/baselines.h"
#include "flat/eval/image_metrics.h"
#include "flat/eval/latent_spread.h"
#include "flat/eval/normal_metrics.h"
#include "test_support.h"

using namespace flat::eval;
namespace eval = flat::eval;

namespace {

// Deterministic analytic images (V=2, C=3, H=24, W=32), float64:
//   a = 0.5 + 0.4 sin(0.37x + 0.23y + 1.1c + 0.5v)
//   b = 0.5 + 0.3 cos(0.21x - 0.29y + 0.7c) + 0.15 sin(0.05xy + c + v)
//   b2 = a + 0.1 sin(1.7x) cos(2.3y)
struct Patterns {
  at::Tensor a, b, b2;
};
Patterns patterns() {
  const int64_t V = 2, C = 3, H = 24, W = 32;
  auto x = at::arange(W, at::kDouble).view({1, 1, 1, W});
  auto y = at::arange(H, at::kDouble).view({1, 1, H, 1});
  auto c = at::arange(C, at::kDouble).view({1, C, 1, 1});
  auto v = at::arange(V, at::kDouble).view({V, 1, 1, 1});
  Patterns p;
  p.a = (0.5 + 0.4 * at::sin(0.37 * x + 0.23 * y + 1.1 * c + 0.5 * v)).expand({V, C, H, W}).contiguous();
  p.b = (0.5 + 0.3 * at::cos(0.21 * x - 0.29 * y + 0.7 * c) + 0.15 * at::sin(0.05 * x * y + c + v))
            .expand({V, C, H, W}).contiguous();
  p.b2 = (p.a + 0.1 * at::sin(1.7 * x) * at::cos(2.3 * y)).contiguous();
  return p;
}

// A per-view metric (V) against each view's reference value, to a relative `eps`.
void check_per_view(const at::Tensor& got, const std::vector<double>& want, double eps) {
  REQUIRE(got.numel() == int64_t(want.size()));
  for (size_t v = 0; v < want.size(); ++v) {
    INFO("view " << v);
    CHECK(got[int64_t(v)].item<double>() == Approx(want[v]).epsilon(eps));
  }
}

}  // namespace

// Reference values: scikit-image 0.26.0 / numpy 2.4 in a throwaway venv, on the
// same formulas in float64, per image v:
//   structural_similarity(a[v], b[v], channel_axis=0, gaussian_weights=True,
//       sigma=1.5, use_sample_covariance=False, data_range=1.0)
//   peak_signal_noise_ratio(a[v], b[v], data_range=1.0)
TEST_CASE("SSIM and PSNR match scikit-image on analytic image pairs", "[eval]") {
  auto p = patterns();
  check_per_view(ssim(p.a, p.b), {0.06923615003211213, 0.11419412885833967}, 1e-9);
  check_per_view(ssim(p.a, p.b2), {0.9462230358678374, 0.946210944406258}, 1e-10);
  check_per_view(psnr(p.a, p.b), {8.511896495579215, 8.672224358785561}, 1e-12);
  check_per_view(psnr(p.a, p.b2), {25.90650030242582, 25.90650030242582}, 1e-12);
  // float32 inputs agree to float precision.
  CHECK(ssim(p.a.to(at::kFloat), p.b2.to(at::kFloat))[0].item<double>() == Approx(0.9462230358678374).epsilon(1e-5));
}

TEST_CASE("PSNR of a hand-made pair", "[eval]") {
  auto a = at::zeros({1, 1, 2, 2}, at::kDouble);
  auto b = at::full({1, 1, 2, 2}, 0.1, at::kDouble);  // MSE 0.01 -> 20 dB
  CHECK(psnr(a, b).item<double>() == Approx(20.0).epsilon(1e-12));
  CHECK(std::isinf(psnr(a, a).item<double>()));
  CHECK(psnr(a * 255, b * 255, 255.0).item<double>() == Approx(20.0).epsilon(1e-12));
}

TEST_CASE("normal accuracy: cosine and L1 over valid pixels", "[eval]") {
  auto n = at::zeros({1, 3, 1, 4}, at::kDouble), N = at::zeros({1, 3, 1, 4}, at::kDouble);
  n[0][2][0][0] = -1;   N[0][2][0][0] = -2;    // identical direction: cos 1, L1 0
  n[0][0][0][1] = 1;    N[0][2][0][1] = -1;    // perpendicular: cos 0, L1 (1+0+1)/3
  n[0][2][0][2] = 1;    N[0][2][0][2] = -1;    // masked out
  /* pixel 3: rendered normal zero -> invalid */ N[0][2][0][3] = -1;
  auto mask = at::tensor({1, 1, 0, 1}).to(at::kBool).view({1, 1, 1, 4});
  auto r = normal_accuracy(n, N, mask);
  CHECK(r.valid_pixels == 2);
  CHECK(r.mean_cosine == Approx(0.5));
  CHECK(r.mean_l1 == Approx((0.0 + 2.0 / 3.0) / 2.0));
  auto none = normal_accuracy(n, N, at::zeros({1, 1, 1, 4}, at::kBool));
  CHECK(none.valid_pixels == 0);
  CHECK(std::isnan(none.mean_cosine));
}

TEST_CASE("LPIPS metric wrapper: chunked, no gradient", "[eval]") {
  torch::manual_seed(3);
  flat::loss::Lpips net;
  auto g = at::make_generator<at::CPUGeneratorImpl>(4);
  auto a = at::rand({3, 3, 16, 16}, g).requires_grad_(true), b = at::rand({3, 3, 16, 16}, g);
  auto d = lpips(net, a, b, 0, 2);
  CHECK(!d.requires_grad());
  CHECK(flat::test::rel_error(d, net->forward(a.detach(), b)) < 1e-6);
}

TEST_CASE("latent spread: correlation across scenes after per-channel standardisation", "[eval]") {
  torch::manual_seed(3);
  const auto channel_offsets = torch::arange(16, at::kFloat).view({16, 1, 1, 1}) * 10.0;
  auto shared = torch::randn({16, 3, 6, 10});
  // Collapsed: one pattern for every scene, with a little scene noise.
  std::vector<at::Tensor> collapsed;
  for (int i = 0; i < 4; ++i) collapsed.push_back(shared + 0.05 * torch::randn({16, 3, 6, 10}) + channel_offsets);
  auto c = eval::latent_spread(collapsed);
  REQUIRE(c.pairs == 6);
  CHECK(c.mean_correlation > 0.99);
  // Independent scenes: near zero, even though every latent carries the same
  // large per-channel offsets (which alone would correlate them near 1).
  std::vector<at::Tensor> independent;
  for (int i = 0; i < 4; ++i) independent.push_back(torch::randn({16, 3, 6, 10}) + channel_offsets);
  auto d = eval::latent_spread(independent);
  CHECK(std::abs(d.mean_correlation) < 0.15);
  CHECK(d.min_correlation <= d.mean_correlation);
  CHECK(d.max_correlation >= d.mean_correlation);
  // A scene and its negation (around the set's channel means) anti-correlate.
  auto a = torch::randn({16, 3, 6, 10});
  auto n = eval::latent_spread({a, -a});
  CHECK(n.mean_correlation == Approx(-1.0).epsilon(1e-9));
  // Different shapes are not compared.
  auto u = eval::latent_spread({a, torch::randn({16, 2, 6, 10})});
  CHECK(u.pairs == 0);
  CHECK(std::isnan(u.mean_correlation));
}

TEST_CASE("baselines: leave-one-out frame mean, cyclic swap partners, mean-colour oracle", "[eval]") {
  eval::FrameSums sums;
  auto x = torch::full({3, 4, 5}, 0.2), y = torch::full({3, 4, 5}, 0.6), z = torch::full({3, 4, 5}, 1.0);
  sums.add(0, x);
  sums.add(0, y);
  sums.add(0, z);
  sums.add(1, x);
  auto loo = sums.leave_one_out(0, x);
  REQUIRE(loo.has_value());
  CHECK(flat::test::rel_error(*loo, torch::full({3, 4, 5}, 0.8)) < 1e-6);  // (0.6 + 1.0) / 2
  CHECK_FALSE(sums.leave_one_out(1, x).has_value());  // no other scene has frame 1
  CHECK_FALSE(sums.leave_one_out(2, x).has_value());
  REQUIRE_THROWS_WITH(sums.add(0, torch::zeros({3, 2, 2})), FLAT_CONTAINS("frame 0"));
  // Merging sets equals adding their frames one by one.
  eval::FrameSums a, b;
  a.add(0, x);
  b.add(0, y);
  b.add(0, z);
  a.add(b);
  CHECK(flat::test::rel_error(*a.leave_one_out(0, y), torch::full({3, 4, 5}, 0.6)) < 1e-6);  // (0.2 + 1.0) / 2
  CHECK(*eval::swap_partner(0, 3) == 1);
  CHECK(*eval::swap_partner(2, 3) == 0);
  CHECK_FALSE(eval::swap_partner(0, 1).has_value());
  // The oracle of a view of one colour is exact (zero error: infinite PSNR).
  auto flat_view = torch::full({1, 3, 4, 4}, 0.3);
  auto two = torch::cat({torch::zeros({1, 3, 4, 2}), torch::ones({1, 3, 4, 2})}, 3);  // mean 0.5, MSE 0.25
  CHECK(eval::mean_colour_psnr(two)[0].item<double>() == Approx(10.0 * std::log10(4.0)).epsilon(1e-6));
  CHECK(eval::mean_colour_psnr(flat_view)[0].item<double>() > 60.0);
}
