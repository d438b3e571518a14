// CUDA kernels against the CPU reference on random scenes: every forward
// output and every gradient. Tolerances are those recorded in
// docs/rasterizer.md ("Tolerances held"). Skipped without a GPU.
#include <torch/torch.h>

#include "flat/render/rasterize.h"
#include "render_scenes.h"
#include "support/raster_checks.h"
#include "test_support.h"

using flat::render::rasterize;
using flat::render::RasterSettings;

namespace {

// CUDA vs CPU, float32 both. Forward: relative L2 error, and the fraction of
// elements that differ by more than 1e-4 (a fragment whose alpha sits within
// rounding of alpha_min may be kept on one side and skipped on the other).
constexpr double kForwardTol = 1e-4;
constexpr double kForwardMismatchFraction = 1e-3;
constexpr double kGradTol = 2e-3;
// Vertices: long float32 chains (1/area, 1/edge) and fragments within
// rounding of a kink of the window (u_i + eps reaching 1) or of the depth
// clamp, which CPU and GPU can send down different branches: a handful of
// triangles then differ by O(their gradient). So: at most kVertexOutliers of
// the triangles may differ by more than 1e-3 of the largest gradient, and the
// others must agree to kVertexGradTol (relative L2). A wrong kernel moves
// most triangles and fails both.
constexpr double kVertexGradTol = 1e-3;
constexpr double kVertexOutliers = 0.01;

flat::test::Rendered run(const flat::test::Soup& soup, const flat::camera::Cameras& cams, int64_t H, int64_t W,
                         const RasterSettings& s, const torch::Device& dev, const flat::test::Probe& probe) {
  auto render = [&](const std::vector<torch::Tensor>& in) {
    return rasterize(in[0], in[1], in[2], in[3], cams.to(dev), H, W, s);
  };
  return flat::test::render_with_grads({soup.vertices, soup.colors, soup.opacities, soup.sigmas}, dev, render, probe);
}

// Loss weights of V views of H x W pixels (rgb, alpha, depth, normal), from
// the global generator.
flat::test::Probe loss_weights(int64_t V, int64_t H, int64_t W) {
  return flat::test::Probe(V, H, W, {/*normal=*/true}, std::nullopt, torch::kFloat);
}

// cams_in: the cameras (default: flat::test::test_cameras(V)).
void compare(int64_t n, int64_t V, int64_t H, int64_t W, const RasterSettings& s, uint64_t seed, double size = 0.5,
             const flat::camera::Cameras* cams_in = nullptr) {
  auto soup = flat::test::random_soup(n, torch::kFloat, seed, size);
  auto cams = cams_in ? *cams_in : flat::test::test_cameras(V);
  const flat::test::Probe w = loss_weights(V, H, W);
  auto cpu = run(soup, cams, H, W, s, torch::kCPU, w);
  auto gpu = run(soup, cams, H, W, s, torch::Device(torch::kCUDA, 0), w);
  const char* out_names[] = {"rgb", "alpha", "depth", "normal", "median_depth", "max_weight"};
  const torch::Tensor c_out[] = {cpu.out.rgb, cpu.out.alpha, cpu.out.depth, cpu.out.normal, cpu.out.median_depth,
                                 cpu.out.max_weight};
  const torch::Tensor g_out[] = {gpu.out.rgb, gpu.out.alpha, gpu.out.depth, gpu.out.normal, gpu.out.median_depth,
                                 gpu.out.max_weight};
  for (int i = 0; i < 6; ++i) {
    const flat::test::OutputDiff d = flat::test::output_diff(g_out[i], c_out[i]);
    const double e = d.rel, frac = (double)d.n_off / (double)c_out[i].numel();
    INFO(out_names[i] << " rel error " << e << ", fraction differing by > 1e-4: " << frac);
    std::printf("cuda-vs-cpu seed %llu %s: rel %.2e, fraction > 1e-4: %.2e\n", (unsigned long long)seed, out_names[i], e,
                frac);
    CHECK(e < kForwardTol);
    CHECK(frac < kForwardMismatchFraction);
  }
  REQUIRE(cpu.out.alpha.max().item<float>() > 0.5f);
  const char* g_names[] = {"vertices", "colors", "opacities", "sigmas"};
  for (int i = 0; i < 4; ++i) {
    const double e = flat::test::rel_error(gpu.grads[i], cpu.grads[i]);
    INFO("grad " << g_names[i] << " rel error " << e);
    std::printf("cuda-vs-cpu seed %llu grad %s: rel %.2e\n", (unsigned long long)seed, g_names[i], e);
    CHECK(torch::isfinite(gpu.grads[i]).all().item<bool>());
    if (i > 0) {
      CHECK(e < kGradTol);
      continue;
    }
    const flat::test::GradOutliers o = flat::test::gradient_outliers(gpu.grads[0], cpu.grads[0], n);
    const double frac = (double)o.count / (double)n, e_rest = o.rel_rest;
    INFO("vertex gradient outliers " << frac << ", rel error of the others " << e_rest);
    std::printf("cuda-vs-cpu seed %llu grad vertices: %lld outlier triangles of %lld, rel error of the others %.2e\n",
                (unsigned long long)seed, (long long)o.count, (long long)n, e_rest);
    CHECK(frac <= kVertexOutliers);
    CHECK(e_rest < kVertexGradTol);
  }
}

}  // namespace

TEST_CASE("rasterize cuda: matches the CPU reference (FLAT window, V = 1)", "[render][cuda]") {
  FLAT_REQUIRE_CUDA();
  compare(200, 1, 40, 56, RasterSettings{}, 101);
}

TEST_CASE("rasterize cuda: matches the CPU reference (FLAT window, V = 3, partial tiles, background)", "[render][cuda]") {
  FLAT_REQUIRE_CUDA();
  RasterSettings s;
  s.background = {0.3, 0.6, 0.1};
  s.eps = 0.3;
  compare(500, 3, 45, 70, s, 202);
}

TEST_CASE("rasterize cuda: matches the CPU reference (Triangle Splatting window)", "[render][cuda]") {
  FLAT_REQUIRE_CUDA();
  RasterSettings s;
  s.window = "ts";
  compare(300, 2, 40, 56, s, 303);
}

TEST_CASE("rasterize cuda: many triangles per tile (several shared-memory batches) and large triangles", "[render][cuda]") {
  FLAT_REQUIRE_CUDA();
  compare(1500, 2, 32, 48, RasterSettings{}, 404, 1.5);
}

TEST_CASE("rasterize cuda: tiny triangles (2x2-pixel scale) match the CPU reference", "[render][cuda]") {
  FLAT_REQUIRE_CUDA();
  compare(3000, 2, 64, 96, RasterSettings{}, 505, 0.05);
}

TEST_CASE("rasterize cuda: views binned two at a time or one at a time give the same images and gradients",
          "[render][cuda]") {
  FLAT_REQUIRE_CUDA();
  // Five views, view 1 turned away from the scene: with two views a bin
  // group that is a group with an empty view, a full group and a last group
  // of one view.
  const int64_t n = 800, V = 5, H = 45, W = 70;
  auto cams = flat::test::test_cameras(V);
  auto R = cams.c2w[1].narrow(0, 0, 3).narrow(1, 0, 3);
  R.select(1, 0).mul_(-1.0);  // half a turn about the camera's y axis: it looks down -z
  R.select(1, 2).mul_(-1.0);
  for (int views_per_bin : {1, 2}) {
    RasterSettings s;
    s.views_per_bin = views_per_bin;
    INFO("views_per_bin " << views_per_bin);
    torch::manual_seed(707);  // the same loss weights both times, whatever ran before
    compare(n, V, H, W, s, 707, 0.5, &cams);
  }
  // The compositing sees the same lists in the same order either way: the
  // images are equal bit for bit; the gradients differ only by the order of
  // their atomic additions.
  auto soup = flat::test::random_soup(n, torch::kFloat, 708, 0.5);
  const flat::test::Probe w = loss_weights(V, H, W);
  const torch::Device dev(torch::kCUDA, 0);
  RasterSettings one, two;
  one.views_per_bin = 1;
  two.views_per_bin = 2;
  const flat::test::Rendered a = run(soup, cams, H, W, one, dev, w), b = run(soup, cams, H, W, two, dev, w);
  REQUIRE(a.out.alpha[1].abs().max().item<float>() == 0.0f);  // the turned view sees nothing
  REQUIRE(a.out.alpha[0].max().item<float>() > 0.5f);
  CHECK(torch::equal(a.out.rgb, b.out.rgb));
  CHECK(torch::equal(a.out.alpha, b.out.alpha));
  CHECK(torch::equal(a.out.depth, b.out.depth));
  CHECK(torch::equal(a.out.normal, b.out.normal));
  CHECK(torch::equal(a.out.median_depth, b.out.median_depth));
  CHECK(torch::equal(a.out.max_weight, b.out.max_weight));
  for (int i = 0; i < 4; ++i) {
    INFO("gradient " << i);
    CHECK(flat::test::rel_error(b.grads[i], a.grads[i]) < 1e-5);
  }
}

TEST_CASE("rasterize cuda: empty scene and culled triangles", "[render][cuda]") {
  FLAT_REQUIRE_CUDA();
  const torch::Device dev(torch::kCUDA, 0);
  auto cams = flat::test::test_cameras(2).to(dev);
  auto opts = torch::TensorOptions().device(dev);
  auto v = torch::zeros({0, 3, 3}, opts).requires_grad_(true);
  auto out = rasterize(v, torch::zeros({0, 3}, opts), torch::zeros({0}, opts), torch::zeros({0}, opts), cams, 20, 30,
                       RasterSettings{});
  CHECK(out.alpha.abs().max().item<float>() == 0.0f);
  out.rgb.sum().backward();
  CHECK(v.grad().numel() == 0);
  auto behind = torch::tensor({{{-1.0f, -1.0f, -2.0f}, {1.0f, -1.0f, -2.0f}, {0.0f, 1.0f, -2.0f}}}, opts);
  auto r = rasterize(behind, torch::ones({1, 3}, opts), torch::full({1}, 0.9f, opts), torch::ones({1}, opts), cams, 20,
                     30, RasterSettings{});
  CHECK(r.alpha.abs().max().item<float>() == 0.0f);
}

TEST_CASE("rasterize cuda: the cameras get no gradient, with the scene frozen or not", "[render][cuda]") {
  FLAT_REQUIRE_CUDA();
  // The cameras reach the kernels as a call's settings, not as autograd
  // inputs: a frozen scene gives outputs that need no gradient (and the
  // forward keeps no backward state); a scene that learns gets its gradient
  // and the cameras none.
  const torch::Device dev(torch::kCUDA, 0);
  auto soup = flat::test::random_soup(200, torch::kFloat, 606, 0.5);
  auto cams = flat::test::test_cameras(2).to(dev);
  cams.c2w = cams.c2w.clone().requires_grad_(true);
  auto frozen = rasterize(soup.vertices.to(dev), soup.colors.to(dev), soup.opacities.to(dev), soup.sigmas.to(dev),
                          cams, 40, 56, RasterSettings{});
  REQUIRE(frozen.alpha.max().item<float>() > 0.0f);
  CHECK_FALSE(frozen.rgb.requires_grad());
  auto colors = soup.colors.to(dev).requires_grad_(true);
  auto out = rasterize(soup.vertices.to(dev), colors, soup.opacities.to(dev), soup.sigmas.to(dev), cams, 40, 56,
                       RasterSettings{});
  REQUIRE(out.rgb.requires_grad());
  REQUIRE_NOTHROW(out.rgb.sum().backward());
  CHECK(colors.grad().abs().sum().item<double>() > 0.0);
  CHECK((!cams.c2w.grad().defined() || cams.c2w.grad().abs().sum().item<double>() == 0.0));
}

TEST_CASE("rasterize cuda: bad input values are reported by name (checked at the back end's first sync)",
          "[render][cuda][errors]") {
  FLAT_REQUIRE_CUDA();
  // The value checks run on the GPU without a sync of their own; they must
  // still stop the call with the input's name, whichever view count.
  const torch::Device dev(torch::kCUDA, 0);
  auto soup = flat::test::random_soup(300, torch::kFloat, 707, 0.5);
  auto cams = flat::test::test_cameras(4).to(dev);
  const auto v = soup.vertices.to(dev), c = soup.colors.to(dev), o = soup.opacities.to(dev), s = soup.sigmas.to(dev);
  auto nan_vertices = v.clone();
  nan_vertices[7][1][2] = std::nanf("");
  REQUIRE_THROWS_WITH(rasterize(nan_vertices, c, o, s, cams, 40, 56, RasterSettings{}), FLAT_CONTAINS("vertices"));
  auto inf_colors = c.clone();
  inf_colors[3][0] = INFINITY;
  REQUIRE_THROWS_WITH(rasterize(v, inf_colors, o, s, cams, 40, 56, RasterSettings{}), FLAT_CONTAINS("colors"));
  REQUIRE_THROWS_WITH(rasterize(v, c, o * 3, s, cams, 40, 56, RasterSettings{}), FLAT_CONTAINS("opacities"));
  REQUIRE_THROWS_WITH(rasterize(v, c, o, -s, cams, 40, 56, RasterSettings{}), FLAT_CONTAINS("sigmas"));
  // With no view the back end never waits for a view's sizes: still checked.
  auto no_views = flat::test::test_cameras(1).to(dev);
  no_views.c2w = no_views.c2w.narrow(0, 0, 0);
  no_views.intrinsics = no_views.intrinsics.narrow(0, 0, 0);
  REQUIRE_THROWS_WITH(rasterize(nan_vertices, c, o, s, no_views, 40, 56, RasterSettings{}), FLAT_CONTAINS("vertices"));
  // The same call with good values still renders after the failures.
  REQUIRE(rasterize(v, c, o, s, cams, 40, 56, RasterSettings{}).alpha.max().item<float>() > 0.0f);
}
