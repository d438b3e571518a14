// The depth measures of depth_metrics.h (issue #44, texture leaking into
// depth) against plain per-pixel loops on small synthetic depth maps.
#include <cmath>

#include "flat/eval/depth_metrics.h"
#include "test_support.h"

using namespace flat::eval;

namespace {

constexpr int64_t V = 2, H = 12, W = 16;

// A plane seen by a pinhole camera: inverse depth affine in the pixel (view v tilted differently).
at::Tensor plane_depth() {
  auto z = at::zeros({V, 1, H, W}, at::kDouble);
  auto a = z.accessor<double, 4>();
  for (int64_t v = 0; v < V; ++v)
    for (int64_t y = 0; y < H; ++y)
      for (int64_t x = 0; x < W; ++x) a[v][0][y][x] = 1.0 / (0.3 + 0.01 * double(x) + (0.015 - 0.01 * double(v)) * double(y));
  return z;
}

// rendered = reference * (1 + e (-1)^(x+y)): the colour's checkerboard leaked into depth.
at::Tensor with_checkerboard(const at::Tensor& z, double e) {
  auto out = z.clone();
  auto a = out.accessor<double, 4>();
  for (int64_t v = 0; v < z.size(0); ++v)
    for (int64_t y = 0; y < z.size(2); ++y)
      for (int64_t x = 0; x < z.size(3); ++x) a[v][0][y][x] *= 1.0 + e * (((x + y) % 2) ? -1.0 : 1.0);
  return out;
}

// Plain rho at one interior pixel: z(p) * (mean of 1/z over the 8 neighbours - 1/z(p)); NaN without depth.
double plain_rho(const at::Tensor& z, int64_t v, int64_t y, int64_t x) {
  auto a = z.accessor<double, 4>();
  double sum = 0;
  for (int64_t dy = -1; dy <= 1; ++dy)
    for (int64_t dx = -1; dx <= 1; ++dx) {
      const double n = a[v][0][y + dy][x + dx];
      if (!(n > 0)) return NAN;
      if (dy != 0 || dx != 0) sum += 1.0 / n;
    }
  return a[v][0][y][x] * (sum / 8.0 - 1.0 / a[v][0][y][x]);
}

// Plain planar roughness with depth only: mean over interior pixels with |rho(ref)| < tolerance
// and a rendered 3x3 of |rho(r) - rho(ref)|; -1 when there is none.
double plain_roughness(const at::Tensor& r, const at::Tensor& ref, int64_t* pixels = nullptr) {
  double sum = 0;
  int64_t n = 0;
  for (int64_t v = 0; v < r.size(0); ++v)
    for (int64_t y = 1; y + 1 < r.size(2); ++y)
      for (int64_t x = 1; x + 1 < r.size(3); ++x) {
        const double pr = plain_rho(r, v, y, x), pR = plain_rho(ref, v, y, x);
        if (!std::isfinite(pr) || !std::isfinite(pR) || !(std::abs(pR) < kPlanarDepthTolerance)) continue;
        sum += std::abs(pr - pR);
        ++n;
      }
  if (pixels) *pixels = n;
  return n ? sum / double(n) : -1;
}

// Eigen et al.'s formula as written, per view, over pixels where both depths are > 0 and mask is set.
double plain_si(const at::Tensor& r, const at::Tensor& ref, const at::Tensor& mask, int64_t v) {
  auto a = r.accessor<double, 4>(), b = ref.accessor<double, 4>();
  auto m = mask.accessor<bool, 4>();
  double s1 = 0, s2 = 0;
  int64_t n = 0;
  for (int64_t y = 0; y < r.size(2); ++y)
    for (int64_t x = 0; x < r.size(3); ++x)
      if (m[v][0][y][x] && a[v][0][y][x] > 0 && b[v][0][y][x] > 0) {
        const double d = std::log(a[v][0][y][x]) - std::log(b[v][0][y][x]);
        s1 += d;
        s2 += d * d;
        ++n;
      }
  return n ? std::sqrt(s2 / double(n) - (s1 / double(n)) * (s1 / double(n))) : NAN;
}

}  // namespace

TEST_CASE("depth measures: a render equal to the reference, or a multiple of it, scores 0", "[eval][depth]") {
  const auto ref = plane_depth();
  const auto all = at::ones({V, 1, H, W}, at::kBool);
  auto same = depth_accuracy(ref, ref, all);
  REQUIRE(same.si_log.size() == size_t(V));
  for (double s : same.si_log) CHECK(s == 0.0);
  CHECK(same.planar_pixels == V * (H - 2) * (W - 2));  // a plane: every interior pixel is planar
  CHECK(same.planar_roughness() == 0.0);
  CHECK(same.depth_pixels == V * H * W);
  // A global scale: the scale-invariant figures stay 0 while a plain log error does not.
  auto scaled = depth_accuracy(1.7 * ref, ref, all);
  for (double s : scaled.si_log) CHECK(s < 1e-12);
  CHECK(scaled.planar_roughness() < 1e-12);
  const double plain_log_rmse = ((1.7 * ref).log() - ref.log()).square().mean().sqrt().item<double>();
  CHECK(plain_log_rmse == Approx(std::log(1.7)));
}

TEST_CASE("SI-log error: Eigen et al.'s formula per view over the masked pixels", "[eval][depth]") {
  const auto ref = plane_depth();
  auto g = at::make_generator<at::CPUGeneratorImpl>(7);
  auto r = ref * (1.0 + 0.2 * at::rand({V, 1, H, W}, g, at::kDouble));
  auto mask = at::rand({V, 1, H, W}, g, at::kDouble) > 0.3;
  r[0][0][2][3] = 0.0;  // no rendered depth: not scored
  auto si = si_log_error(r, ref, mask);
  REQUIRE(si.size(0) == V);
  for (int64_t v = 0; v < V; ++v) {
    CHECK(si[v].item<double>() > 0.01);
    CHECK(si[v].item<double>() == Approx(plain_si(r, ref, mask, v)).epsilon(1e-9));
  }
  // A view without a valid pixel has no figure (NaN), not 0.
  mask[1].fill_(false);
  auto part = si_log_error(r, ref, mask);
  CHECK(std::isfinite(part[0].item<double>()));
  CHECK(std::isnan(part[1].item<double>()));
}

TEST_CASE("planar roughness: a checkerboard leaked into a planar depth raises it in proportion", "[eval][depth]") {
  const auto ref = plane_depth();
  const auto all = at::ones({V, 1, H, W}, at::kBool);
  // rho of the plain loop, pixel by pixel.
  auto rho = relative_disparity_laplacian(with_checkerboard(ref, 0.01));
  for (int64_t y = 1; y + 1 < H; ++y)
    for (int64_t x = 1; x + 1 < W; ++x)
      CHECK(rho[1][0][y][x].item<double>() == Approx(plain_rho(with_checkerboard(ref, 0.01), 1, y, x)).margin(1e-14));
  CHECK(std::isnan(rho[0][0][0][5].item<double>()));  // the border has no 3x3 neighbourhood

  auto r1 = depth_accuracy(with_checkerboard(ref, 0.01), ref, all);
  auto r2 = depth_accuracy(with_checkerboard(ref, 0.02), ref, all);
  int64_t n1 = 0;
  CHECK(r1.planar_roughness() == Approx(plain_roughness(with_checkerboard(ref, 0.01), ref, &n1)).epsilon(1e-10));
  CHECK(r1.planar_pixels == n1);
  // A 1-pixel checkerboard of relative amplitude e gives |rho| ~ e (up to e^2).
  CHECK(r1.planar_roughness() == Approx(0.01).epsilon(0.03));
  CHECK(r2.planar_roughness() / r1.planar_roughness() == Approx(2.0).epsilon(0.03));
  // The SI-log error sees it too (over every pixel, flat or not).
  CHECK(r1.si_log[0] > 0.005);

  // One uncovered pixel (alpha <= 0.5) takes itself and its 8 neighbours out of the roughness.
  auto mask = all.clone();
  mask[0][0][5][6] = false;
  auto holed = depth_accuracy(with_checkerboard(ref, 0.01), ref, mask);
  CHECK(holed.planar_pixels == r1.planar_pixels - 9);
  CHECK(holed.depth_pixels == V * H * W - 1);
}

TEST_CASE("planar mask: step edges, and creases where normals exist, are not planar", "[eval][depth]") {
  // A step from 2 m to 3 m between columns 7 and 8.
  auto step = at::full({1, 1, H, W}, 2.0, at::kDouble);
  step.slice(3, 8, W).fill_(3.0);
  auto m = planar_mask(step);
  for (int64_t y = 1; y + 1 < H; ++y) {
    CHECK_FALSE(m[0][0][y][7].item<bool>());
    CHECK_FALSE(m[0][0][y][8].item<bool>());
    CHECK(m[0][0][y][6].item<bool>());
    CHECK(m[0][0][y][9].item<bool>());
    CHECK_FALSE(m[0][0][y][0].item<bool>());  // border
  }
  // A render that moves the edge by one column: the planar pixels beside it
  // see the move in their 3x3, pixels away from it do not.
  auto moved = step.clone();
  moved.slice(3, 7, 8).fill_(3.0);
  auto acc = depth_accuracy(moved, step, at::ones_like(step, at::kBool));
  CHECK(acc.planar_pixels == (H - 2) * (W - 4));
  CHECK(acc.planar_roughness() > 0);  // column 6 sees the moved edge

  // A shallow crease (continuous depth, |rho| below the tolerance at the kink):
  // planar by depth alone, not planar where the reference normals change.
  auto crease = at::zeros({1, 1, H, W}, at::kDouble);
  auto normals = at::zeros({1, 3, H, W}, at::kDouble);
  for (int64_t x = 0; x < W; ++x) {
    crease.select(3, x).fill_(1.0 / (0.3 + 0.0005 * std::abs(double(x) - 8.0)));
    normals[0][0].select(1, x).fill_(x < 8 ? 0.1 : -0.1);
  }
  normals[0][2].fill_(-1.0);
  const double kink = plain_rho(crease, 0, 5, 8);
  REQUIRE(std::abs(kink) > 1e-4);
  REQUIRE(std::abs(kink) < kPlanarDepthTolerance);
  auto by_depth = planar_mask(crease);
  auto with_normals = planar_mask(crease, normals);
  for (int64_t y = 1; y + 1 < H; ++y) {
    CHECK(by_depth[0][0][y][7].item<bool>());
    CHECK(by_depth[0][0][y][8].item<bool>());
    CHECK_FALSE(with_normals[0][0][y][7].item<bool>());
    CHECK_FALSE(with_normals[0][0][y][8].item<bool>());
    CHECK(with_normals[0][0][y][6].item<bool>());
    CHECK(with_normals[0][0][y][9].item<bool>());
  }
  // Zero normals mean no reference normal: not planar.
  normals.select(3, 3).zero_();
  CHECK_FALSE(planar_mask(crease, normals)[0][0][5][4].item<bool>());
}

TEST_CASE("depth measures: no reference depth gives no figure (NaN), not 0", "[eval][depth]") {
  const auto r = plane_depth();
  auto none = depth_accuracy(r, at::zeros_like(r), at::ones({V, 1, H, W}, at::kBool));
  REQUIRE(none.si_log.size() == size_t(V));
  for (double s : none.si_log) CHECK(std::isnan(s));
  CHECK(none.planar_pixels == 0);
  CHECK(none.depth_pixels == 0);
  CHECK(std::isnan(none.planar_roughness()));
  // Shapes are checked and named.
  REQUIRE_THROWS_WITH(depth_accuracy(r, r.slice(3, 0, 8), {}), FLAT_CONTAINS("reference depth"));
  REQUIRE_THROWS_WITH(si_log_error(r, r, at::ones({V, 1, H, 3}, at::kBool)), FLAT_CONTAINS("mask"));
}
