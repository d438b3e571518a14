// CPU reference Gaussian rasterizer: analytic gradients against central
// finite differences in double precision, outputs against closed forms, edge
// cases and input checks.
#include <torch/torch.h>

#include <cmath>

#include "flat/core/error.h"
#include "flat/gaussians/rasterize_gaussians.h"
#include "gaussian_scenes.h"
#include "gaussians/gaussian_math.h"
#include "support/raster_checks.h"
#include "test_support.h"

using flat::gaussians::rasterize_gaussians;
using flat::render::CompositingSettings;
using flat::render::RenderOutput;

namespace {

constexpr int64_t kH = 18, kW = 24;

RenderOutput render(const std::vector<torch::Tensor>& in, const flat::camera::Cameras& cams, const CompositingSettings& s,
                    int64_t H = kH, int64_t W = kW) {
  return rasterize_gaussians(in[0], in[1], in[2], in[3], in[4], cams, H, W, s);
}

void check_gradients_fd(const CompositingSettings& settings, uint64_t seed, bool with_offscreen) {
  const int64_t N = 8, V = 2;
  auto g = flat::test::random_gaussians(N, torch::kDouble, seed);
  if (with_offscreen) {
    // Gaussian 0 lies beyond the image's right edge (x/z = 0.77 > 1.3x the
    // half-extent 0.72): J's clamp is active, and it still reaches the image.
    g.means[0] = torch::tensor({2.3, 0.1, 3.0}, torch::kDouble);
    g.scales[0] = torch::tensor({0.5, 0.4, 0.45}, torch::kDouble);
    g.opacities[0] = 0.8;
  }
  auto cams = flat::test::test_cameras(V);
  const flat::test::Probe probe(V, kH, kW, {}, at::make_generator<at::CPUGeneratorImpl>(seed + 1), torch::kDouble);
  std::vector<torch::Tensor> inputs = {g.means, g.scales, g.rotations, g.colors, g.opacities};
  for (auto& t : inputs) t.requires_grad_(true);
  auto render_inputs = [&](const std::vector<torch::Tensor>& in) { return render(in, cams, settings); };
  auto out = render_inputs(inputs);
  REQUIRE(out.alpha.max().item<double>() > 0.3);  // the scene is visible
  auto grads = torch::autograd::grad({probe(out)}, inputs);
  flat::test::check_against_fd(inputs, grads, {"means", "scales", "rotations", "colors", "opacities"}, render_inputs,
                               probe);
  if (with_offscreen) CHECK(grads[0][0].abs().sum().item<double>() > 0.0);  // the clamped one gets gradient
}

// One Gaussian (N = 1), double.
std::vector<torch::Tensor> one(std::vector<double> mean, double scale, double opacity, std::vector<double> color) {
  return {torch::tensor(mean, torch::kDouble).view({1, 3}), torch::full({1, 3}, scale, torch::kDouble),
          torch::tensor({1.0, 0.0, 0.0, 0.0}, torch::kDouble).view({1, 4}),
          torch::tensor(color, torch::kDouble).view({1, 3}), torch::full({1}, opacity, torch::kDouble)};
}

std::vector<torch::Tensor> cat(const std::vector<torch::Tensor>& a, const std::vector<torch::Tensor>& b) {
  std::vector<torch::Tensor> r;
  for (size_t i = 0; i < a.size(); ++i) r.push_back(torch::cat({a[i], b[i]}));
  return r;
}

}  // namespace

TEST_CASE("rasterize_gaussians cpu: gradients of every input match central finite differences (double)",
          "[gaussians][grad]") {
  check_gradients_fd(CompositingSettings{}, 11, false);
}

TEST_CASE("rasterize_gaussians cpu: clamped Jacobian, background, larger Gaussians: gradients match FD",
          "[gaussians][grad]") {
  CompositingSettings s;
  s.background = {0.2, 0.5, 0.9};
  check_gradients_fd(s, 23, true);
}

TEST_CASE("rasterize_gaussians cpu: opacities at the alpha cap and no alpha_min: gradients match FD",
          "[gaussians][grad]") {
  CompositingSettings s;
  s.alpha_min = 0.0;
  s.alpha_max = 0.6;  // most centres hit the cap: no gradient through alpha there
  check_gradients_fd(s, 37, false);
}

TEST_CASE("rasterize_gaussians cpu: an isotropic Gaussian on the optical axis has the closed-form alpha and depth",
          "[gaussians]") {
  // Odd image size: the principal point (W/2, H/2) is the centre of pixel (12, 9).
  const int64_t H = 19, W = 25, xc = 12, yc = 9;
  auto cams = flat::test::test_cameras(1);  // view 0: identity pose, fx = 0.9 W, fy = 1.2 H
  // The scale whose projection, dilated by 0.3 px^2, is 2 px along x:
  // (fx s / z)^2 + 0.3 = 4.
  const double fx = 0.9 * W, fy = 1.2 * H, z = 2.0, o = 0.8;
  const double s = z * std::sqrt(4.0 - 0.3) / fx;
  auto out = render(one({0.0, 0.0, z}, s, o, {0.2, 0.4, 0.6}), cams, CompositingSettings{}, H, W);
  // 2-D covariance diag(fx^2 s^2 / z^2 + 0.3, fy^2 s^2 / z^2 + 0.3) (J at u = v = 0).
  const double vx = fx * fx * s * s / (z * z) + 0.3, vy = fy * fy * s * s / (z * z) + 0.3;
  REQUIRE(vx == Approx(4.0));
  auto alpha = [&](int64_t y, int64_t x) { return out.alpha[0][0][y][x].item<double>(); };
  CHECK(alpha(yc, xc) == Approx(o).epsilon(1e-6));                       // float cameras
  CHECK(alpha(yc, xc + 2) == Approx(o * std::exp(-0.5)).epsilon(1e-5));  // one projected sigma
  CHECK(alpha(yc, xc - 2) == Approx(o * std::exp(-0.5)).epsilon(1e-5));
  for (int64_t d : {1, 3}) {
    CHECK(alpha(yc, xc + d) == Approx(o * std::exp(-0.5 * d * d / vx)).epsilon(1e-5));
    CHECK(alpha(yc - d, xc) == Approx(o * std::exp(-0.5 * d * d / vy)).epsilon(1e-5));
  }
  CHECK(alpha(yc + 1, xc + 2) == Approx(o * std::exp(-0.5 * (4.0 / vx + 1.0 / vy))).epsilon(1e-5));
  const double sigma_px = std::sqrt(vx);
  // Depth is alpha-weighted; colour too.
  CHECK(out.depth[0][0][yc][xc + 1].item<double>() / alpha(yc, xc + 1) == Approx(z).epsilon(1e-12));
  CHECK(out.rgb[0][2][yc][xc].item<double>() == Approx(0.6 * alpha(yc, xc)).epsilon(1e-12));
  CHECK(out.median_depth[0][0][yc][xc].item<double>() == Approx(z));
  CHECK(out.max_weight[0].item<double>() == Approx(alpha(yc, xc)));
  CHECK(!out.normal.defined());
  CHECK(!out.distortion.defined());
  // The support is the 3-sigma ellipse q <= 9, even where o exp(-q/2) would
  // still pass alpha_min (here 0): 3.5 sigmas out (7 px) is empty, 2.5 is not.
  CompositingSettings no_min;
  no_min.alpha_min = 0.0;
  auto cut = render(one({0.0, 0.0, z}, s, o, {0.2, 0.4, 0.6}), cams, no_min, H, W);
  CHECK(cut.alpha[0][0][yc][xc + 5].item<double>() == Approx(o * std::exp(-0.5 * 25.0 / vx)).epsilon(1e-5));
  CHECK(cut.alpha[0][0][yc][xc + 7].item<double>() == 0.0);
  CHECK(sigma_px == Approx(2.0));
}

TEST_CASE(
    "rasterize_gaussians cpu: the EWA covariance and the 1.3x clamp of J's screen position follow the closed form",
    "[gaussians]") {
  // An isotropic Gaussian at camera position (X, Y, z) has the 2-D covariance
  // (s/z)^2 J0 J0^T + 0.3 I, J0 = [[fx, 0, -fx u], [0, fy, -fy v]], with
  // u = X/z, v = Y/z clamped to 1.3x the half-extent about the principal
  // point ([-0.722, 0.722] in x here); the mean projects unclamped.
  const int64_t H = 19, W = 25;
  auto cams = flat::test::test_cameras(1);
  const double fx = 0.9 * W, fy = 1.2 * H, cx = 0.5 * W, cy = 0.5 * H, z = 2.0;
  const double lim_x = (W - cx) / fx + 0.3 * 0.5 * W / fx;
  struct Case {
    double X, Y, s;
  };
  for (const Case& cs : {Case{0.6, -0.3, 0.12}, Case{1.8, 0.2, 0.5}}) {  // inside; clamped (X/z = 0.9)
    auto out = render(one({cs.X, cs.Y, z}, cs.s, 0.9, {1.0, 1.0, 1.0}), cams, CompositingSettings{}, H, W);
    const double u = std::min(cs.X / z, lim_x), v = cs.Y / z, k = cs.s * cs.s / (z * z);
    const double a = k * fx * fx * (1 + u * u) + 0.3, b = k * fx * fy * u * v, c = k * fy * fy * (1 + v * v) + 0.3;
    const double det = a * c - b * b;
    const double mx = fx * cs.X / z + cx, my = fy * cs.Y / z + cy;
    int64_t lit = 0;
    for (int64_t y = 0; y < H; ++y)
      for (int64_t x = 0; x < W; ++x) {
        const double dx = x + 0.5 - mx, dy = y + 0.5 - my;
        const double q = (c * dx * dx - 2 * b * dx * dy + a * dy * dy) / det;
        const double e = 0.9 * std::exp(-0.5 * q);
        if (std::abs(q - 9.0) < 1e-3 || std::abs(e - 1.0 / 255.0) < 1e-5) continue;  // at a cut: either side
        const double expect = q <= 9.0 && e >= 1.0 / 255.0 ? e : 0.0;
        lit += expect > 0.0;
        INFO("X " << cs.X << " pixel " << x << "," << y << " q " << q);
        CHECK(out.alpha[0][0][y][x].item<double>() == Approx(expect).margin(1e-6).epsilon(1e-5));
      }
    CHECK(lit > 10);
  }
}

TEST_CASE("rasterize_gaussians cpu: two Gaussians composite front to back by depth, not by index", "[gaussians]") {
  const int64_t H = 19, W = 25, xc = 12, yc = 9;
  auto cams = flat::test::test_cameras(1);
  CompositingSettings s;
  s.background = {0.1, 0.2, 0.3};
  // Index 0 is the far one (green), index 1 the near one (red).
  auto far = one({0.0, 0.0, 4.0}, 0.3, 0.6, {0.0, 1.0, 0.0});
  auto near = one({0.0, 0.0, 2.0}, 0.15, 0.7, {1.0, 0.0, 0.0});
  auto out = render(cat(far, near), cams, s, H, W);
  const double a1 = 0.7, a2 = 0.6;  // both centred on pixel (12, 9)
  const double T = (1 - a1) * (1 - a2);
  CHECK(out.rgb[0][0][yc][xc].item<double>() == Approx(a1 * 1.0 + T * 0.1).epsilon(1e-5));
  CHECK(out.rgb[0][1][yc][xc].item<double>() == Approx((1 - a1) * a2 * 1.0 + T * 0.2).epsilon(1e-5));
  CHECK(out.rgb[0][2][yc][xc].item<double>() == Approx(T * 0.3).epsilon(1e-5));
  CHECK(out.alpha[0][0][yc][xc].item<double>() == Approx(1 - T).epsilon(1e-5));
  CHECK(out.depth[0][0][yc][xc].item<double>() == Approx(a1 * 2.0 + (1 - a1) * a2 * 4.0).epsilon(1e-5));
  CHECK(out.median_depth[0][0][yc][xc].item<double>() == Approx(2.0));  // T falls below 0.5 at the near one
  // Where nothing reaches: the background, alpha 0, depth 0.
  CHECK(out.rgb[0][2][0][0].item<double>() == Approx(0.3));
  CHECK(out.alpha[0][0][0][0].item<double>() == 0.0);
  CHECK(out.depth[0][0][0][0].item<double>() == 0.0);
}

TEST_CASE("rasterize_gaussians cpu: Gaussians behind the camera or the near plane are culled", "[gaussians][edge]") {
  auto cams = flat::test::test_cameras(1);
  auto in = cat(one({0.0, 0.0, -2.0}, 0.5, 0.9, {1, 1, 1}), one({0.0, 0.0, 0.005}, 0.5, 0.9, {1, 1, 1}));
  for (auto& t : in) t.requires_grad_(true);
  auto out = render(in, cams, CompositingSettings{});
  CHECK(out.alpha.abs().max().item<double>() == 0.0);
  CHECK(out.max_weight.abs().max().item<double>() == 0.0);
  (out.rgb.sum() + out.depth.sum() + out.alpha.sum()).backward();
  for (auto& t : in) {
    CHECK(torch::isfinite(t.grad()).all().item<bool>());
    CHECK(t.grad().abs().max().item<double>() == 0.0);
  }
}

TEST_CASE("rasterize_gaussians cpu: the quaternion's norm does not matter; its gradient is orthogonal to it",
          "[gaussians]") {
  auto g = flat::test::random_gaussians(12, torch::kDouble, 5);
  auto cams = flat::test::test_cameras(2);
  auto rot = g.rotations.clone().requires_grad_(true);
  auto a = rasterize_gaussians(g.means, g.scales, rot, g.colors, g.opacities, cams, kH, kW, CompositingSettings{});
  auto b =
      rasterize_gaussians(g.means, g.scales, g.rotations * 3.0, g.colors, g.opacities, cams, kH, kW, CompositingSettings{});
  CHECK((a.rgb - b.rgb).abs().max().item<double>() < 1e-12);
  a.rgb.sum().backward();
  CHECK((rot.grad() * g.rotations).sum(1).abs().max().item<double>() < 1e-10);
  CHECK(rot.grad().abs().max().item<double>() > 0.0);
}

TEST_CASE("rasterize_gaussians cpu: empty scene renders the background and returns empty gradients",
          "[gaussians][edge]") {
  auto cams = flat::test::test_cameras(2);
  auto m = torch::zeros({0, 3}).requires_grad_(true);
  auto s = torch::zeros({0, 3}), q = torch::zeros({0, 4}), c = torch::zeros({0, 3}), o = torch::zeros({0});
  CompositingSettings settings;
  settings.background = flat::test::kEmptySceneBackground;
  flat::test::check_empty_scene(rasterize_gaussians(m, s, q, c, o, cams, kH, kW, settings), kH, kW, m);
}

TEST_CASE("rasterize_gaussians cpu: many Gaussians in one pixel stop at the transmittance floor", "[gaussians][edge]") {
  auto cams = flat::test::test_cameras(1);
  const int64_t n = 400;
  auto z = torch::linspace(2.0, 5.0, n, torch::kFloat);
  auto means = torch::stack({torch::zeros({n}), torch::zeros({n}), z}, 1);
  auto out = rasterize_gaussians(means, torch::full({n, 3}, 0.2f), torch::tensor({1.f, 0.f, 0.f, 0.f}).repeat({n, 1}),
                                 torch::rand({n, 3}), torch::full({n}, 0.5f), cams, kH, kW, CompositingSettings{});
  flat::test::check_transmittance_floor(out, n);
}

TEST_CASE("rasterize_gaussians cpu: V views at once equal one view at a time", "[gaussians]") {
  auto g = flat::test::random_gaussians(40, torch::kFloat, 6);
  flat::test::check_views_independent(
      [&](const flat::camera::Cameras& c) {
        return rasterize_gaussians(g.means, g.scales, g.rotations, g.colors, g.opacities, c, kH, kW,
                                   CompositingSettings{});
      },
      flat::test::test_cameras(3));
}

TEST_CASE("rasterize_gaussians cpu: other float dtypes are cast and gradients come back in their dtype",
          "[gaussians]") {
  auto g = flat::test::random_gaussians(6, torch::kFloat, 9);
  auto m = g.means.to(torch::kBFloat16).requires_grad_(true);
  auto out = rasterize_gaussians(m, g.scales, g.rotations, g.colors, g.opacities, flat::test::test_cameras(1), kH, kW,
                                 CompositingSettings{});
  CHECK(out.rgb.scalar_type() == torch::kFloat);
  out.rgb.sum().backward();
  CHECK(m.grad().scalar_type() == torch::kBFloat16);
}

TEST_CASE("rasterize_gaussians cpu: bad inputs are reported with their name and expected shape",
          "[gaussians][errors]") {
  auto g = flat::test::random_gaussians(4, torch::kFloat, 3);
  auto cams = flat::test::test_cameras(1);
  auto call = [&](const torch::Tensor& m, const torch::Tensor& s, const torch::Tensor& q, const torch::Tensor& c,
                  const torch::Tensor& o) {
    return rasterize_gaussians(m, s, q, c, o, cams, kH, kW, CompositingSettings{});
  };
  REQUIRE_THROWS_WITH(call(g.means.view({-1}), g.scales, g.rotations, g.colors, g.opacities),
                      FLAT_CONTAINS("means") && FLAT_CONTAINS("(N,3)"));
  REQUIRE_THROWS_WITH(call(g.means, g.scales.narrow(1, 0, 2), g.rotations, g.colors, g.opacities),
                      FLAT_CONTAINS("scales") && FLAT_CONTAINS("(N,3)"));
  REQUIRE_THROWS_WITH(call(g.means, g.scales, g.rotations.narrow(1, 0, 3), g.colors, g.opacities),
                      FLAT_CONTAINS("rotations") && FLAT_CONTAINS("(N,4)"));
  REQUIRE_THROWS_WITH(call(g.means, g.scales, g.rotations, g.colors.narrow(0, 0, 3), g.opacities),
                      FLAT_CONTAINS("colors") && FLAT_CONTAINS("N = 4"));
  REQUIRE_THROWS_WITH(call(g.means, g.scales, g.rotations, g.colors, g.opacities.view({4, 1})),
                      FLAT_CONTAINS("opacities") && FLAT_CONTAINS("(N)"));
  auto nan_means = g.means.clone();
  nan_means[2][1] = std::nanf("");
  REQUIRE_THROWS_WITH(call(nan_means, g.scales, g.rotations, g.colors, g.opacities), FLAT_CONTAINS("means"));
  REQUIRE_THROWS_WITH(call(g.means, g.scales, g.rotations, g.colors, g.opacities * 3), FLAT_CONTAINS("opacities"));
  REQUIRE_THROWS_WITH(call(g.means, -g.scales, g.rotations, g.colors, g.opacities), FLAT_CONTAINS("scales"));
  REQUIRE_THROWS_WITH(call(g.means, g.scales, g.rotations * 0, g.colors, g.opacities), FLAT_CONTAINS("rotations"));
  CompositingSettings bad;
  bad.background = {1.0};
  REQUIRE_THROWS_WITH(rasterize_gaussians(g.means, g.scales, g.rotations, g.colors, g.opacities, cams, kH, kW, bad),
                      FLAT_CONTAINS("background"));
}

TEST_CASE("gaussian maths: quaternion rotation is orthonormal and its backward matches FD", "[gaussians][math]") {
  using namespace flat::gaussians;
  const double q[4] = {0.3, -0.5, 0.7, 0.4};
  double n = 0;
  for (double v : q) n += v * v;
  double qn[4];
  for (int i = 0; i < 4; ++i) qn[i] = q[i] / std::sqrt(n);
  double R[9];
  quat_to_rotation(qn, R);
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) {
      double dot = 0;
      for (int k = 0; k < 3; ++k) dot += R[3 * a + k] * R[3 * b + k];
      CHECK(dot == Approx(a == b ? 1.0 : 0.0).margin(1e-12));
    }
  const double G[9] = {0.1, -0.2, 0.3, 0.4, -0.5, 0.6, -0.7, 0.8, 0.9};
  double gq[4];
  quat_to_rotation_backward(qn, G, gq);
  for (int i = 0; i < 4; ++i) {
    double qp[4], qm[4], Rp[9], Rm[9];
    for (int j = 0; j < 4; ++j) qp[j] = qm[j] = qn[j];
    qp[i] += 1e-6, qm[i] -= 1e-6;
    quat_to_rotation(qp, Rp);
    quat_to_rotation(qm, Rm);
    double fd = 0;
    for (int j = 0; j < 9; ++j) fd += G[j] * (Rp[j] - Rm[j]) / 2e-6;
    CHECK(gq[i] == Approx(fd).epsilon(1e-7));
  }
}

TEST_CASE(
    "gaussian maths: min_q_over_rect is the minimum over the rectangle, and the tile test keeps every "
    "kept fragment",
    "[gaussians][math]") {
  using namespace flat::gaussians;
  auto g = flat::test::random_gaussians(60, torch::kDouble, 17, 0.05, 0.6);
  auto cams = flat::test::test_cameras(1);
  const int64_t H = 45, W = 70;
  const at::Tensor w2c = flat::camera::world_to_camera(cams.c2w.to(torch::kDouble)).contiguous();
  const at::Tensor K = flat::camera::pixel_intrinsics(cams.intrinsics, H, W).to(torch::kDouble).contiguous();
  const CameraView<double> cam = make_camera_view(w2c.data_ptr<double>(), K.data_ptr<double>());
  CompositingConstants k;
  auto gen = at::make_generator<at::CPUGeneratorImpl>(3);
  int64_t checked = 0, kept = 0;
  for (int64_t n = 0; n < 60; ++n) {
    ScreenGaussian<double> sg{};
    PixelBox box{};
    const double op = g.opacities[n].item<double>();
    if (!preprocess_forward(g.means[n].data_ptr<double>(), g.scales[n].data_ptr<double>(),
                            g.rotations[n].data_ptr<double>(), op, cam, k, (int)W, (int)H, sg, box))
      continue;
    sg.opacity = op;
    // Against brute force on a fine grid, for random rectangles around the mean.
    for (int t = 0; t < 5; ++t) {
      auto r = at::rand({4}, gen, torch::kDouble) * 16.0 - 8.0;
      const double x0 = sg.mx + std::min(r[0].item<double>(), r[1].item<double>());
      const double x1 = sg.mx + std::max(r[0].item<double>(), r[1].item<double>());
      const double y0 = sg.my + std::min(r[2].item<double>(), r[3].item<double>());
      const double y1 = sg.my + std::max(r[2].item<double>(), r[3].item<double>());
      double brute = 1e30;
      for (int i = 0; i <= 200; ++i)
        for (int j = 0; j <= 200; ++j)
          brute =
              std::min(brute, quad_form(sg, x0 + (x1 - x0) * i / 200.0 - sg.mx, y0 + (y1 - y0) * j / 200.0 - sg.my));
      const double exact = min_q_over_rect(sg, x0, x1, y0, y1);
      CHECK(exact <= brute + 1e-12);
      CHECK(exact >= brute - 1e-3 * (1.0 + brute));
      ++checked;
    }
    // The CUDA binning's test (preprocess.cu, tile_mask) on 16x16 tiles: a
    // tile holding a kept fragment is never dropped.
    for (int y = box.y0; y < box.y1; ++y)
      for (int x = box.x0; x < box.x1; ++x) {
        Fragment<double> f;
        if (!shade(sg, x + 0.5, y + 0.5, k, f)) continue;
        ++kept;
        const int tx = x / 16, ty = y / 16;
        const double rx0 = std::max(box.x0, tx * 16) + 0.5, rx1 = std::min(box.x1, (tx + 1) * 16) - 1 + 0.5;
        const double ry0 = std::max(box.y0, ty * 16) + 0.5, ry1 = std::min(box.y1, (ty + 1) * 16) - 1 + 0.5;
        CHECK(min_q_over_rect(sg, rx0, rx1, ry0, ry1) <= sg.extent2);
      }
  }
  CHECK(checked > 100);
  CHECK(kept > 100);
}
