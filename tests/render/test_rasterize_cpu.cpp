// CPU reference rasterizer: analytic gradients against central finite
// differences in double precision, outputs against closed forms, edge cases.
#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/render/rasterize.h"
#include "render_scenes.h"
#include "support/raster_checks.h"
#include "test_support.h"

using flat::render::rasterize;
using flat::render::RasterSettings;
using flat::render::RenderOutput;

namespace {

constexpr int64_t kH = 18, kW = 24;

void check_gradients_fd(const RasterSettings& settings, uint64_t seed) {
  const int64_t N = 7, V = 2;
  auto soup = flat::test::random_soup(N, torch::kDouble, seed);
  auto cams = flat::test::test_cameras(V);
  const flat::test::Probe probe(V, kH, kW, {/*normal=*/true}, at::make_generator<at::CPUGeneratorImpl>(seed + 1),
                                torch::kDouble);
  auto render = [&](const std::vector<torch::Tensor>& in) {
    return rasterize(in[0], in[1], in[2], in[3], cams, kH, kW, settings);
  };
  std::vector<torch::Tensor> inputs = {soup.vertices, soup.colors, soup.opacities, soup.sigmas};
  for (auto& t : inputs) t.requires_grad_(true);
  auto out = render(inputs);
  REQUIRE(out.alpha.max().item<double>() > 0.3);  // the scene is visible
  auto grads = torch::autograd::grad({probe(out)}, inputs);
  flat::test::check_against_fd(inputs, grads, {"vertices", "colors", "opacities", "sigmas"}, render, probe);
}

RasterSettings defaults() { return RasterSettings{}; }

}  // namespace

TEST_CASE("rasterize cpu: FLAT window gradients match central finite differences (double)", "[render][grad]") {
  check_gradients_fd(defaults(), 11);
}

TEST_CASE("rasterize cpu: FLAT window, non-black background, wide eps: gradients match FD", "[render][grad]") {
  auto s = defaults();
  s.eps = 0.4;
  s.background = {0.2, 0.5, 0.9};
  check_gradients_fd(s, 23);
}

TEST_CASE("rasterize cpu: Triangle Splatting window gradients match FD", "[render][grad]") {
  auto s = defaults();
  s.window = "ts";
  check_gradients_fd(s, 37);
}

TEST_CASE("rasterize cpu: fronto-parallel triangle gives exact alpha, depth and normal", "[render]") {
  // Camera at the origin; a big triangle at z = 2 covering the image centre.
  auto cams = flat::test::test_cameras(1);
  auto v = torch::tensor({{{-3.0, -3.0, 2.0}, {3.0, -3.0, 2.0}, {0.0, 3.0, 2.0}}}, torch::kDouble);
  auto c = torch::tensor({{0.2, 0.4, 0.6}}, torch::kDouble);
  auto o = torch::tensor({0.7}, torch::kDouble), s = torch::tensor({1.0}, torch::kDouble);
  auto out = rasterize(v, c, o, s, cams, kH, kW, defaults());
  const int64_t y = kH / 2, x = kW / 2;
  const double a = out.alpha[0][0][y][x].item<double>();
  CHECK(a > 0.1);  // o * I with I < 1 away from the incenter
  CHECK(a <= 0.7 + 1e-12);
  CHECK(out.depth[0][0][y][x].item<double>() / a == Approx(2.0).epsilon(1e-12));
  CHECK(out.normal[0][2][y][x].item<double>() / a == Approx(-1.0).epsilon(1e-12));
  CHECK(out.rgb[0][1][y][x].item<double>() / a == Approx(0.4).epsilon(1e-12));
  CHECK(out.median_depth[0][0][y][x].item<double>() == Approx(2.0));
  CHECK(out.max_weight[0].item<double>() == Approx(out.alpha.max().item<double>()));
}

TEST_CASE("rasterize cpu: per-pixel depth is the ray-plane intersection of a tilted triangle", "[render]") {
  auto cams = flat::test::test_cameras(1);
  // Plane z = 3 + 0.5 x (tilted), triangle large enough to cover the image.
  auto plane_z = [](double x) { return 3.0 + 0.5 * x; };
  auto v = torch::tensor({{{-2.0, -3.0, plane_z(-2.0)}, {2.0, -3.0, plane_z(2.0)}, {0.0, 3.0, plane_z(0.0)}}},
                         torch::kDouble);
  auto out = rasterize(v, torch::full({1, 3}, 0.5, torch::kDouble), torch::full({1}, 0.9, torch::kDouble),
                       torch::full({1}, 1.0, torch::kDouble), cams, kH, kW, defaults());
  // Ray through pixel (x, y): d = ((x+0.5-cx)/fx, (y+0.5-cy)/fy, 1); z = 3 / (1 - 0.5 dx).
  const double fx = 0.9 * kW, cx = 0.5 * kW;
  for (int64_t x : {4, 10, 15}) {
    const int64_t y = kH / 2;
    const double dx = (x + 0.5 - cx) / fx;
    const double a = out.alpha[0][0][y][x].item<double>();
    REQUIRE(a > 0.1);
    CHECK(out.depth[0][0][y][x].item<double>() / a == Approx(3.0 / (1.0 - 0.5 * dx)).epsilon(1e-6)  /* float cameras */);
  }
  // Normal faces the camera: n . (point) < 0.
  CHECK(out.normal[0][2][kH / 2][kW / 2].item<double>() < 0.0);
}

TEST_CASE("rasterize cpu: empty scene renders the background and returns empty gradients", "[render][edge]") {
  auto cams = flat::test::test_cameras(2);
  auto v = torch::zeros({0, 3, 3}, torch::kFloat).requires_grad_(true);
  auto c = torch::zeros({0, 3}, torch::kFloat).requires_grad_(true);
  auto o = torch::zeros({0}, torch::kFloat), s = torch::zeros({0}, torch::kFloat);
  auto settings = defaults();
  settings.background = flat::test::kEmptySceneBackground;
  flat::test::check_empty_scene(rasterize(v, c, o, s, cams, kH, kW, settings), kH, kW, v);
}

TEST_CASE("rasterize cpu: triangles behind the camera, crossing the near plane, edge-on or degenerate are culled", "[render][edge]") {
  auto cams = flat::test::test_cameras(1);
  auto v = torch::tensor({{{-1.0, -1.0, -2.0}, {1.0, -1.0, -2.0}, {0.0, 1.0, -2.0}},    // behind
                          {{-1.0, -1.0, 2.0}, {1.0, -1.0, 2.0}, {0.0, 1.0, -0.5}},     // crosses near plane
                          {{0.0, -1.0, 2.0}, {0.0, 1.0, 2.0}, {0.0, 0.0, 3.0}},        // edge-on (plane x = 0)
                          {{-1.0, 0.0, 2.0}, {0.0, 0.0, 2.0}, {1.0, 0.0, 2.0}},        // collinear
                          {{0.1, 0.1, 2.0}, {0.1, 0.1, 2.0}, {0.1, 0.1, 2.0}}},        // a point
                         torch::kDouble)
               .requires_grad_(true);
  auto c = torch::rand({5, 3}, torch::kDouble).requires_grad_(true);
  auto o = torch::full({5}, 0.9, torch::kDouble), s = torch::ones({5}, torch::kDouble);
  auto out = rasterize(v, c, o, s, cams, kH, kW, defaults());
  CHECK(out.alpha.abs().max().item<double>() == 0.0);
  (out.rgb.sum() + out.depth.sum() + out.normal.sum()).backward();
  CHECK(torch::isfinite(v.grad()).all().item<bool>());
  CHECK(v.grad().abs().max().item<double>() == 0.0);
}

TEST_CASE("rasterize cpu: a triangle much larger than the image covers every pixel", "[render][edge]") {
  auto cams = flat::test::test_cameras(1);
  auto v = torch::tensor({{{-200.0, -200.0, 2.0}, {200.0, -200.0, 2.0}, {0.0, 300.0, 2.0}}}, torch::kFloat)
               .requires_grad_(true);
  auto o = torch::full({1}, 0.8), s = torch::ones({1});
  auto out = rasterize(v, torch::ones({1, 3}), o, s, cams, kH, kW, defaults());
  CHECK(out.alpha.min().item<float>() > 0.5f);
  out.alpha.sum().backward();
  CHECK(torch::isfinite(v.grad()).all().item<bool>());
}

TEST_CASE("rasterize cpu: many triangles in one pixel saturate alpha and stop at the transmittance floor", "[render][edge]") {
  auto cams = flat::test::test_cameras(1);
  const int64_t n = 600;
  auto z = torch::linspace(2.0, 5.0, n, torch::kFloat);
  auto v = torch::zeros({n, 3, 3});
  // Fronto-parallel triangles centred on the optical axis, each covering a few pixels.
  for (int k = 0; k < 3; ++k) {
    const double ang = 2.0 * M_PI * k / 3.0 + M_PI / 2;
    v.select(1, k).select(1, 0).copy_(0.15 * std::cos(ang) * z);
    v.select(1, k).select(1, 1).copy_(0.15 * std::sin(ang) * z);
    v.select(1, k).select(1, 2).copy_(z);
  }
  auto out = rasterize(v, torch::rand({n, 3}), torch::full({n}, 0.5), torch::ones({n}), cams, kH, kW, defaults());
  // The front triangle dominates; the deepest one only ever gets a sliver of
  // weight (at most a (1-a)^599 <= 6e-4 at pixels of small alpha a).
  flat::test::check_transmittance_floor(out, n);
}

TEST_CASE("rasterize cpu: V views at once equal one view at a time", "[render]") {
  auto soup = flat::test::random_soup(30, torch::kFloat, 5);
  flat::test::check_views_independent(
      [&](const flat::camera::Cameras& c) {
        return rasterize(soup.vertices, soup.colors, soup.opacities, soup.sigmas, c, kH, kW, defaults());
      },
      flat::test::test_cameras(3));
}

TEST_CASE("rasterize cpu: float inputs of other dtypes are cast and gradients come back in their dtype", "[render]") {
  auto soup = flat::test::random_soup(5, torch::kFloat, 9);
  auto v = soup.vertices.to(torch::kBFloat16).requires_grad_(true);
  auto out = rasterize(v, soup.colors, soup.opacities, soup.sigmas, flat::test::test_cameras(1), kH, kW, defaults());
  CHECK(out.rgb.scalar_type() == torch::kFloat);
  out.rgb.sum().backward();
  CHECK(v.grad().scalar_type() == torch::kBFloat16);
}

TEST_CASE("rasterize cpu: bad inputs are reported with their name and shape", "[render][errors]") {
  auto soup = flat::test::random_soup(4, torch::kFloat, 3);
  auto cams = flat::test::test_cameras(1);
  REQUIRE_THROWS_WITH(rasterize(soup.vertices.view({4, 9}), soup.colors, soup.opacities, soup.sigmas, cams, kH, kW,
                                defaults()),
                      FLAT_CONTAINS("vertices"));
  REQUIRE_THROWS_WITH(rasterize(soup.vertices, soup.colors.narrow(0, 0, 3), soup.opacities, soup.sigmas, cams, kH,
                                kW, defaults()),
                      FLAT_CONTAINS("colors"));
  auto bad = soup.colors.clone();
  bad[1][1] = std::nanf("");
  REQUIRE_THROWS_WITH(rasterize(soup.vertices, bad, soup.opacities, soup.sigmas, cams, kH, kW, defaults()),
                      FLAT_CONTAINS("colors"));
  REQUIRE_THROWS_WITH(rasterize(soup.vertices, soup.colors, soup.opacities * 3, soup.sigmas, cams, kH, kW, defaults()),
                      FLAT_CONTAINS("opacities"));
  auto s = defaults();
  s.window = "box";
  REQUIRE_THROWS_WITH(rasterize(soup.vertices, soup.colors, soup.opacities, soup.sigmas, cams, kH, kW, s),
                      FLAT_CONTAINS("window"));
}

TEST_CASE("raster settings: read from YAML through the config visitor, bad values named", "[render][config]") {
  auto s = flat::config::parse<RasterSettings>("window: ts\neps: 0.2\nbackground: [1, 0.5, 0]\n", "raster.yaml");
  CHECK(s.window == "ts");
  CHECK(s.eps == Approx(0.2));
  CHECK(s.background[1] == Approx(0.5));
  CHECK(s.alpha_min == Approx(1.0 / 255.0));  // untouched defaults
  REQUIRE_THROWS_WITH(flat::config::parse<RasterSettings>("window: box\n", "raster.yaml"), FLAT_CONTAINS("window"));
  REQUIRE_THROWS_WITH(flat::config::parse<RasterSettings>("eps: 3\n", "raster.yaml"), FLAT_CONTAINS("eps"));
  REQUIRE_THROWS_WITH(flat::config::parse<RasterSettings>("views_per_bin: 3\n", "raster.yaml"),
                      FLAT_CONTAINS("views_per_bin"));
  CHECK(flat::config::parse<RasterSettings>("views_per_bin: 2\n", "raster.yaml").views_per_bin == 2);
  auto bad = RasterSettings{};
  bad.background = {1.0, 1.0};
  REQUIRE_THROWS_WITH(bad.check(), FLAT_CONTAINS("background"));
  bad = RasterSettings{};
  bad.views_per_bin = 0;
  REQUIRE_THROWS_WITH(bad.check(), FLAT_CONTAINS("views_per_bin"));
  // Built in code, checked against the ranges visit() declares (written once).
  bad = RasterSettings{};
  bad.eps = 3;
  REQUIRE_THROWS_WITH(bad.check(), FLAT_CONTAINS("raster settings: 'eps': expected"));
  bad = RasterSettings{};
  bad.background = {2.0, 0.0, 0.0};
  REQUIRE_THROWS_WITH(bad.check(), FLAT_CONTAINS("'background'"));
  bad = RasterSettings{};
  bad.alpha_min = 0.5;
  bad.alpha_max = 0.4;
  REQUIRE_THROWS_WITH(bad.check(), FLAT_CONTAINS("must be below 'alpha_max'"));
}
