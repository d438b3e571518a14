// CPU reference surfel rasterizer: analytic gradients against central finite
// differences in double precision, outputs against closed forms, edge cases.
#include <torch/torch.h>

#include "flat/camera/cameras.h"
#include "flat/core/error.h"
#include "flat/loss/regularisers_2dgs.h"
#include "flat/surfels/rasterize_surfels.h"
#include "support/raster_checks.h"
#include "surfel_scenes.h"
#include "test_support.h"

using flat::render::CompositingSettings;
using flat::render::RenderOutput;
using flat::surfels::rasterize_surfels;

namespace {

constexpr int64_t kH = 18, kW = 24;

RenderOutput render(const flat::test::Surfels& s, const flat::camera::Cameras& cams,
                    const CompositingSettings& settings = CompositingSettings{}, int64_t H = kH, int64_t W = kW) {
  return rasterize_surfels(s.means, s.scales, s.rotations, s.colors, s.opacities, cams, H, W, settings);
}

void check_gradients_fd(const CompositingSettings& settings, uint64_t seed, bool only_distortion, double scale_lo = 0.03,
                        double scale_hi = 0.4) {
  const int64_t N = 8, V = 2;
  auto scene = flat::test::random_surfels(N, torch::kDouble, seed, scale_lo, scale_hi);
  auto cams = flat::test::test_cameras(V);
  flat::test::ProbeOutputs which;
  which.normal = which.distortion = true;
  which.only_distortion = only_distortion;
  const flat::test::Probe probe(V, kH, kW, which, at::make_generator<at::CPUGeneratorImpl>(seed + 1), torch::kDouble);
  std::vector<torch::Tensor> inputs = {scene.means, scene.scales, scene.rotations, scene.colors, scene.opacities};
  for (auto& t : inputs) t.requires_grad_(true);
  auto render_inputs = [&](const std::vector<torch::Tensor>& in) {
    return render(flat::test::Surfels{in[0], in[1], in[2], in[3], in[4]}, cams, settings);
  };
  auto out = render_inputs(inputs);
  REQUIRE(out.alpha.max().item<double>() > 0.3);  // the scene is visible
  REQUIRE(out.distortion.max().item<double>() > 1e-6);  // surfels overlap
  auto grads = torch::autograd::grad({probe(out)}, inputs);
  // The distortion does not depend on colours (input 3).
  flat::test::check_against_fd(inputs, grads, {"means", "scales", "rotations", "colors", "opacities"}, render_inputs,
                               probe, only_distortion ? 3 : -1);
}

// Pixel intrinsics (fx, fy, cx, cy) of view 0 of the test cameras, in double.
std::vector<double> pixel_k(const flat::camera::Cameras& cams, int64_t H = kH, int64_t W = kW) {
  auto K = flat::camera::pixel_intrinsics(cams.intrinsics.to(torch::kDouble), H, W)[0];
  return {K[0].item<double>(), K[1].item<double>(), K[2].item<double>(), K[3].item<double>()};
}

flat::test::Surfels one_surfel(std::vector<double> mean, std::vector<double> scale, std::vector<double> quat,
                               double opacity, std::vector<double> color = {0.2, 0.4, 0.6}) {
  auto o = torch::TensorOptions().dtype(torch::kDouble);
  return {torch::tensor(mean, o).view({1, 3}), torch::tensor(scale, o).view({1, 2}), torch::tensor(quat, o).view({1, 4}),
          torch::tensor(color, o).view({1, 3}), torch::tensor({opacity}, o)};
}

flat::test::Surfels concat(const flat::test::Surfels& a, const flat::test::Surfels& b) {
  return {torch::cat({a.means, b.means}), torch::cat({a.scales, b.scales}), torch::cat({a.rotations, b.rotations}),
          torch::cat({a.colors, b.colors}), torch::cat({a.opacities, b.opacities})};
}

}  // namespace

TEST_CASE("rasterize_surfels cpu: gradients of every input match central finite differences (double)",
          "[surfels][grad]") {
  check_gradients_fd(CompositingSettings{}, 11, false);
}

TEST_CASE("rasterize_surfels cpu: distortion gradients alone match finite differences", "[surfels][grad]") {
  check_gradients_fd(CompositingSettings{}, 17, true);
}

TEST_CASE("rasterize_surfels cpu: background, low alpha cap and larger surfels: gradients match FD",
          "[surfels][grad]") {
  CompositingSettings s;
  s.background = {0.2, 0.5, 0.9};
  s.alpha_max = 0.8;  // some fragments capped
  check_gradients_fd(s, 23, false, 0.1, 0.6);
}

TEST_CASE("rasterize_surfels cpu: pixel-sized surfels (the low-pass filter wins near their centres): gradients match FD",
          "[surfels][grad]") {
  check_gradients_fd(CompositingSettings{}, 29, false, 0.02, 0.12);
}

TEST_CASE("rasterize_surfels cpu: fronto-parallel surfel gives exact alpha, depth and normal", "[surfels]") {
  auto cams = flat::test::test_cameras(1);
  const auto K = pixel_k(cams);
  const double z = 2.0, su = 0.5, sv = 0.3, o = 0.7;
  // Centre on the ray of pixel (12, 9)'s centre.
  const double X0 = (12.5 - K[2]) / K[0] * z, Y0 = (9.5 - K[3]) / K[1] * z;
  auto out = render(one_surfel({X0, Y0, z}, {su, sv}, {1, 0, 0, 0}, o), cams);
  CHECK(out.alpha[0][0][9][12].item<double>() == Approx(o).epsilon(1e-12));
  int covered = 0;
  for (int64_t y = 0; y < kH; ++y)
    for (int64_t x = 0; x < kW; ++x) {
      const double a = out.alpha[0][0][y][x].item<double>();
      // u, v of the pixel's ray on the plane z = const: exact (the low-pass
      // disc is far smaller than this surfel).
      const double u = ((x + 0.5 - K[2]) / K[0] * z - X0) / su, v = ((y + 0.5 - K[3]) / K[1] * z - Y0) / sv;
      const double expect = o * std::exp(-0.5 * (u * u + v * v));
      INFO("pixel " << x << "," << y);
      if (expect < 1.0 / 255.0) {
        CHECK(a == 0.0);
        continue;
      }
      ++covered;
      CHECK(a == Approx(expect).epsilon(1e-12));
      CHECK(out.depth[0][0][y][x].item<double>() / a == Approx(z).epsilon(1e-12));
      CHECK(out.normal[0][2][y][x].item<double>() / a == Approx(-1.0).epsilon(1e-12));
      CHECK(std::abs(out.normal[0][0][y][x].item<double>()) < 1e-12);
      CHECK(out.rgb[0][1][y][x].item<double>() / a == Approx(0.4).epsilon(1e-12));
      CHECK(out.distortion[0][0][y][x].item<double>() == 0.0);  // one surfel: no pairs
    }
  CHECK(covered > 30);
  CHECK(out.median_depth[0][0][9][12].item<double>() == Approx(z));
  CHECK(out.max_weight[0].item<double>() == Approx(o));
}

TEST_CASE("rasterize_surfels cpu: a tilted surfel's depth follows its plane", "[surfels]") {
  auto cams = flat::test::test_cameras(1);
  const auto K = pixel_k(cams);
  // Plane z = 3 + 0.5 x: t_u = (cos t, 0, sin t) with tan t = 0.5, a turn of -t about y.
  const double t = std::atan(0.5);
  auto out = render(one_surfel({0.0, 0.0, 3.0}, {1.5, 1.5}, {std::cos(-t / 2), 0.0, std::sin(-t / 2), 0.0}, 0.9), cams);
  for (int64_t x : {2, 4, 10, 15, 21}) {
    const int64_t y = kH / 2 + 2;
    const double dx = (x + 0.5 - K[2]) / K[0];
    const double a = out.alpha[0][0][y][x].item<double>();
    REQUIRE(a > 0.1);
    CHECK(out.depth[0][0][y][x].item<double>() / a == Approx(3.0 / (1.0 - 0.5 * dx)).epsilon(1e-10));
  }
  // The normal (-sin t, 0, cos t) turned to face the camera.
  const double a = out.alpha[0][0][kH / 2][kW / 2].item<double>();
  CHECK(out.normal[0][0][kH / 2][kW / 2].item<double>() / a == Approx(std::sin(t)).epsilon(1e-10));
  CHECK(out.normal[0][2][kH / 2][kW / 2].item<double>() / a == Approx(-std::cos(t)).epsilon(1e-10));
}

TEST_CASE("rasterize_surfels cpu: the normal is turned to face the camera", "[surfels]") {
  auto cams = flat::test::test_cameras(1);
  // The same surfel seen from its front (t_w = -z) and its back (t_w = +z,
  // the quaternion of half a turn about x, scaled: not unit).
  auto front = render(one_surfel({0.1, 0.0, 2.5}, {0.4, 0.4}, {0.0, 2.0, 0.0, 0.0}, 0.8), cams);
  auto back = render(one_surfel({0.1, 0.0, 2.5}, {0.4, 0.4}, {1.0, 0.0, 0.0, 0.0}, 0.8), cams);
  CHECK(front.normal[0][2].min().item<double>() < -0.1);
  CHECK(front.normal[0][2].max().item<double>() <= 0.0);
  CHECK((front.normal - back.normal).abs().max().item<double>() < 1e-12);
  CHECK((front.alpha - back.alpha).abs().max().item<double>() < 1e-12);
}

TEST_CASE("rasterize_surfels cpu: the distortion map equals loss::depth_distortion_reference", "[surfels]") {
  auto cams = flat::test::test_cameras(1);
  // Two overlapping tilted surfels, the second behind: at every pixel the
  // weights are (a1, a2 (1 - a1)) and the depths each one's own.
  auto s1 = one_surfel({0.0, 0.0, 2.0}, {0.5, 0.4}, {std::cos(0.2), std::sin(0.2), 0.0, 0.0}, 0.6);
  auto s2 = one_surfel({0.1, 0.05, 3.0}, {0.6, 0.5}, {std::cos(0.3), 0.0, std::sin(0.3), 0.0}, 0.8);
  auto r1 = render(s1, cams), r2 = render(s2, cams), both = render(concat(s1, s2), cams);
  auto a1 = r1.alpha.view({-1}), a2 = r2.alpha.view({-1});
  auto z1 = r1.depth.view({-1}) / a1.clamp_min(1e-30), z2 = r2.depth.view({-1}) / a2.clamp_min(1e-30);
  auto mask = (a1 > 0) & (a2 > 0);
  REQUIRE(mask.sum().item<int64_t>() > 20);
  auto weights = torch::stack({a1, a2 * (1 - a1)}, 1).index({mask});
  auto depths = torch::stack({z1, z2}, 1).index({mask});
  auto expect = flat::loss::depth_distortion_reference(weights, depths, flat::surfels::kDistortionNear,
                                                       flat::surfels::kDistortionFar);
  auto got = both.distortion.view({-1}).index({mask});
  CHECK(expect.min().item<double>() > 0.0);
  CHECK((got - expect).abs().max().item<double>() < 1e-12 * (1.0 + expect.abs().max().item<double>()));
  // Elsewhere one surfel or none: no pairs.
  CHECK(both.distortion.view({-1}).index({mask.logical_not()}).abs().max().item<double>() == 0.0);
}

TEST_CASE("rasterize_surfels cpu: surfels behind the near plane are culled; background where nothing is",
          "[surfels][edge]") {
  auto cams = flat::test::test_cameras(1);
  auto s = concat(one_surfel({0.0, 0.0, 0.005}, {0.5, 0.5}, {1, 0, 0, 0}, 0.9),   // nearer than near_plane
                  one_surfel({0.0, 0.0, -2.0}, {0.5, 0.5}, {1, 0, 0, 0}, 0.9));   // behind
  for (auto* t : {&s.means, &s.scales, &s.rotations, &s.colors, &s.opacities}) t->requires_grad_(true);
  CompositingSettings settings;
  settings.background = {0.1, 0.2, 0.3};
  auto out = render(s, cams, settings);
  CHECK(out.alpha.abs().max().item<double>() == 0.0);
  CHECK((out.rgb[0][2] - 0.3).abs().max().item<double>() < 1e-12);
  CHECK(out.distortion.abs().max().item<double>() == 0.0);
  (out.rgb.sum() + out.depth.sum() + out.normal.sum() + out.distortion.sum()).backward();
  for (auto* t : {&s.means, &s.scales, &s.rotations, &s.colors, &s.opacities}) {
    CHECK(torch::isfinite(t->grad()).all().item<bool>());
    CHECK(t->grad().abs().max().item<double>() == 0.0);
  }
}

TEST_CASE("rasterize_surfels cpu: empty scene renders the background and returns empty gradients",
          "[surfels][edge]") {
  auto cams = flat::test::test_cameras(2);
  auto m = torch::zeros({0, 3}).requires_grad_(true);
  CompositingSettings settings;
  settings.background = flat::test::kEmptySceneBackground;
  auto out = rasterize_surfels(m, torch::zeros({0, 2}), torch::zeros({0, 4}), torch::zeros({0, 3}), torch::zeros({0}),
                               cams, kH, kW, settings);
  CHECK(out.distortion.sizes() == torch::IntArrayRef({2, 1, kH, kW}));
  flat::test::check_empty_scene(out, kH, kW, m);
}

TEST_CASE("rasterize_surfels cpu: many surfels in one pixel stop at the transmittance floor", "[surfels][edge]") {
  auto cams = flat::test::test_cameras(1);
  const int64_t n = 400;
  auto z = torch::linspace(2.0, 5.0, n, torch::kFloat);
  flat::test::Surfels s{torch::stack({torch::zeros({n}), torch::zeros({n}), z}, 1), (0.1 * z).unsqueeze(1).repeat({1, 2}),
                        torch::tensor({1.f, 0.f, 0.f, 0.f}).repeat({n, 1}), torch::rand({n, 3}), torch::full({n}, 0.5f)};
  flat::test::check_transmittance_floor(render(s, cams), n);
}

TEST_CASE("rasterize_surfels cpu: V views at once equal one view at a time; float matches double", "[surfels]") {
  auto scene = flat::test::random_surfels(30, torch::kFloat, 5);
  auto cams = flat::test::test_cameras(3);
  flat::test::check_views_independent([&](const flat::camera::Cameras& c) { return render(scene, c); }, cams);
  auto all = render(scene, cams);
  flat::test::Surfels d{scene.means.to(torch::kDouble), scene.scales.to(torch::kDouble),
                        scene.rotations.to(torch::kDouble), scene.colors.to(torch::kDouble),
                        scene.opacities.to(torch::kDouble)};
  auto dbl = render(d, cams);
  CHECK(flat::test::rel_error(all.rgb, dbl.rgb) < 1e-5);
  CHECK(flat::test::rel_error(all.depth, dbl.depth) < 1e-5);
  CHECK(flat::test::rel_error(all.distortion, dbl.distortion) < 1e-3);
}

TEST_CASE("rasterize_surfels cpu: bad inputs are reported with their name and shape", "[surfels][errors]") {
  auto s = flat::test::random_surfels(4, torch::kFloat, 3);
  auto cams = flat::test::test_cameras(1);
  auto call = [&](const flat::test::Surfels& x) { return render(x, cams); };
  auto with = [&](int which, torch::Tensor t) {
    flat::test::Surfels x = s;
    torch::Tensor* f[] = {&x.means, &x.scales, &x.rotations, &x.colors, &x.opacities};
    *f[which] = t;
    return x;
  };
  REQUIRE_THROWS_WITH(call(with(0, s.means.view({3, 4}))), FLAT_CONTAINS("means") && FLAT_CONTAINS("(N,3)"));
  REQUIRE_THROWS_WITH(call(with(1, torch::ones({4, 3}))), FLAT_CONTAINS("scales") && FLAT_CONTAINS("(N,2)"));
  REQUIRE_THROWS_WITH(call(with(2, torch::ones({4, 3}))), FLAT_CONTAINS("rotations") && FLAT_CONTAINS("(N,4)"));
  REQUIRE_THROWS_WITH(call(with(3, s.colors.narrow(0, 0, 3))), FLAT_CONTAINS("colors") && FLAT_CONTAINS("(N,3)"));
  REQUIRE_THROWS_WITH(call(with(4, s.opacities.view({4, 1}))), FLAT_CONTAINS("opacities") && FLAT_CONTAINS("(N)"));
  auto nan_means = s.means.clone();
  nan_means[1][2] = std::nanf("");
  REQUIRE_THROWS_WITH(call(with(0, nan_means)), FLAT_CONTAINS("means"));
  REQUIRE_THROWS_WITH(call(with(4, s.opacities * 3)), FLAT_CONTAINS("opacities"));
  REQUIRE_THROWS_WITH(call(with(1, -s.scales)), FLAT_CONTAINS("scales"));
  REQUIRE_THROWS_WITH(call(with(2, torch::zeros({4, 4}))), FLAT_CONTAINS("rotations"));
  REQUIRE_THROWS_AS(call(with(1, torch::ones({4, 3}))), flat::Error);
}
