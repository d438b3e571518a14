// CUDA surfel kernels against the CPU reference on random scenes: every
// forward output and every gradient. Tolerances as docs/rasterizer_2dgs.md
// ("Tolerances"). Skipped without a GPU.
#include <algorithm>
#include <cstdio>

#include <torch/torch.h>

#include "flat/surfels/rasterize_surfels.h"
#include "flat/render/shared/splat_tiles.h"
#include "support/raster_checks.h"
#include "surfel_scenes.h"
#include "test_support.h"

using flat::render::CompositingSettings;
using flat::render::RenderOutput;
using flat::surfels::rasterize_surfels;

namespace {

// CUDA vs CPU, float32 both. Forward: a fragment whose alpha sits within
// rounding of alpha_min, or whose rho3d and rho2d are within rounding of each
// other, or a pixel at the transmittance floor or at T = 0.5 (median depth),
// may take another branch on each side: such elements (off by more than
// 1e-4) may be at most kForwardMismatchFraction of an output, or
// kForwardMismatchMin elements (one such pixel is 3 elements of rgb; alone in
// the 2240 pixels of a small test image it already costs ~7e-5 of rgb's
// relative L2 error, and __expf puts more fragments within rounding than the
// CPU's exp). The others must agree to kForwardTol (relative L2). A wrong
// kernel moves most elements and fails both.
constexpr double kForwardTol = 1e-4;
constexpr double kForwardMismatchFraction = 1e-3;
constexpr double kForwardMismatchMin = 8;
// The distortion sums squared differences of nearby NDC depths: float keeps
// fewer of its digits.
constexpr double kDistortionTol = 1e-3;
constexpr double kGradTol = 2e-3;  // colours, opacities
// Geometry (means, scales, rotations): fragments within rounding of a branch
// (alpha_min, the alpha cap, the low-pass switch, whose depth jumps) can move
// a surfel's gradient by O(itself): at most kGeomOutliers of the surfels (or
// kGeomOutliersMin) may differ by more than 1e-3 of the largest gradient, the
// others must agree to kGeomGradTol (relative L2). A wrong kernel moves most
// surfels and fails both.
constexpr double kGeomGradTol = 2e-3;
constexpr double kGeomOutliers = 0.01;
constexpr double kGeomOutliersMin = 3;

flat::test::Rendered run(const flat::test::Surfels& s, const flat::camera::Cameras& cams, int64_t H, int64_t W,
                         const CompositingSettings& settings, const torch::Device& dev, const flat::test::Probe& probe) {
  auto render = [&](const std::vector<torch::Tensor>& in) {
    return rasterize_surfels(in[0], in[1], in[2], in[3], in[4], cams.to(dev), H, W, settings);
  };
  return flat::test::render_with_grads({s.means, s.scales, s.rotations, s.colors, s.opacities}, dev, render, probe);
}

// only_distortion: the loss weighs the distortion map alone (its gradient
// is otherwise a small part of the total, and colours get none).
void compare(int64_t n, int64_t V, int64_t H, int64_t W, const CompositingSettings& s, uint64_t seed, double scale_lo = 0.03,
             double scale_hi = 0.4, bool only_distortion = false) {
  auto scene = flat::test::random_surfels(n, torch::kFloat, seed, scale_lo, scale_hi);
  // Many views: smaller steps between them, so that all 18 differ and all see the scene.
  auto cams = flat::test::test_cameras(V, V > 4 ? 0.2 : 1.0);
  torch::manual_seed(seed);
  flat::test::ProbeOutputs which;
  which.normal = which.distortion = true;
  which.only_distortion = only_distortion;
  const flat::test::Probe w(V, H, W, which, std::nullopt, torch::kFloat);
  auto cpu = run(scene, cams, H, W, s, torch::kCPU, w);
  auto gpu = run(scene, cams, H, W, s, torch::Device(torch::kCUDA, 0), w);
  const char* out_names[] = {"rgb", "alpha", "depth", "normal", "median_depth", "max_weight", "distortion"};
  const torch::Tensor c_out[] = {cpu.out.rgb,          cpu.out.alpha,      cpu.out.depth,     cpu.out.normal,
                                 cpu.out.median_depth, cpu.out.max_weight, cpu.out.distortion};
  const torch::Tensor g_out[] = {gpu.out.rgb,          gpu.out.alpha,      gpu.out.depth,     gpu.out.normal,
                                 gpu.out.median_depth, gpu.out.max_weight, gpu.out.distortion};
  for (int i = 0; i < 7; ++i) {
    const torch::Tensor g = g_out[i].cpu(), c = c_out[i];
    REQUIRE(g.sizes() == c.sizes());
    const flat::test::OutputDiff d = flat::test::output_diff(g, c);
    const double e = d.rel, e_rest = d.rel_rest;
    const int64_t n_off = d.n_off;
    INFO(out_names[i] << " rel error " << e << ", " << n_off << " of " << c.numel()
                      << " elements off by > 1e-4, rel error of the others " << e_rest);
    std::printf("surfels cuda-vs-cpu seed %llu %s: rel %.2e, %lld of %lld elements off by > 1e-4, rel error of the "
                "others %.2e\n",
                (unsigned long long)seed, out_names[i], e, (long long)n_off, (long long)c.numel(), e_rest);
    CHECK(torch::isfinite(g).all().item<bool>());
    CHECK(e_rest < (i == 6 ? kDistortionTol : kForwardTol));
    CHECK((double)n_off <= std::max(kForwardMismatchFraction * (double)c.numel(), kForwardMismatchMin));
  }
  REQUIRE(cpu.out.alpha.max().item<float>() > 0.5f);
  REQUIRE(cpu.out.distortion.max().item<float>() > 0.0f);
  const char* g_names[] = {"means", "scales", "rotations", "colors", "opacities"};
  for (int i = 0; i < 5; ++i) {
    if (only_distortion && i == 3) continue;  // the distortion does not depend on colours
    REQUIRE(gpu.grads[i].sizes() == cpu.grads[i].sizes());
    const double e = flat::test::rel_error(gpu.grads[i], cpu.grads[i]);
    INFO("grad " << g_names[i] << " rel error " << e);
    std::printf("surfels cuda-vs-cpu seed %llu%s grad %s: rel %.2e\n", (unsigned long long)seed,
                only_distortion ? " (distortion only)" : "", g_names[i], e);
    CHECK(torch::isfinite(gpu.grads[i]).all().item<bool>());
    CHECK(cpu.grads[i].abs().max().item<double>() > 0.0);
    if (i >= 3) {
      CHECK(e < kGradTol);
      continue;
    }
    const flat::test::GradOutliers o = flat::test::gradient_outliers(gpu.grads[i], cpu.grads[i], n);
    const int64_t n_out = o.count;
    const double e_rest = o.rel_rest;
    INFO(g_names[i] << " gradient outliers " << n_out << " of " << n << ", rel error of the others " << e_rest);
    std::printf("surfels cuda-vs-cpu seed %llu%s grad %s: %lld outlier surfels of %lld, rel error of the others %.2e\n",
                (unsigned long long)seed, only_distortion ? " (distortion only)" : "", g_names[i], (long long)n_out,
                (long long)n, e_rest);
    CHECK((double)n_out <= std::max(kGeomOutliers * (double)n, kGeomOutliersMin));
    CHECK(e_rest < kGeomGradTol);
  }
}

}  // namespace

TEST_CASE("rasterize_surfels cuda: matches the CPU reference (V = 1)", "[surfels][cuda]") {
  FLAT_REQUIRE_CUDA();
  compare(200, 1, 40, 56, CompositingSettings{}, 101);
}

TEST_CASE("rasterize_surfels cuda: matches the CPU reference (V = 3, partial tiles, background, alpha cap)",
          "[surfels][cuda]") {
  FLAT_REQUIRE_CUDA();
  CompositingSettings s;
  s.background = {0.3, 0.6, 0.1};
  s.alpha_max = 0.9;
  compare(500, 3, 45, 70, s, 202);
}

TEST_CASE("rasterize_surfels cuda: 18 views, two launches' chunks of views (16 + 2), match the CPU reference",
          "[surfels][cuda]") {
  FLAT_REQUIRE_CUDA();
  REQUIRE(flat::render::splat::chunk_views(18, 300) == 16);  // as the 3DGS case: a wrong offset moves whole views
  CompositingSettings s;
  s.background = {0.2, 0.1, 0.4};
  compare(300, 18, 33, 47, s, 303);
}

TEST_CASE("rasterize_surfels cuda: many surfels per tile (several shared-memory rounds) and large surfels",
          "[surfels][cuda]") {
  FLAT_REQUIRE_CUDA();
  compare(1500, 2, 32, 48, CompositingSettings{}, 303, 0.1, 1.0);
}

TEST_CASE("rasterize_surfels cuda: distortion gradients alone match the CPU reference", "[surfels][cuda]") {
  FLAT_REQUIRE_CUDA();
  compare(500, 2, 40, 56, CompositingSettings{}, 505, 0.03, 0.4, /*only_distortion=*/true);
}

TEST_CASE("rasterize_surfels cuda: pixel-sized surfels (low-pass filter) match the CPU reference", "[surfels][cuda]") {
  FLAT_REQUIRE_CUDA();
  compare(3000, 2, 64, 96, CompositingSettings{}, 404, 0.02, 0.12);
}

TEST_CASE("rasterize_surfels cuda: empty scene, culled surfels and bad values", "[surfels][cuda]") {
  FLAT_REQUIRE_CUDA();
  const torch::Device dev(torch::kCUDA, 0);
  auto cams = flat::test::test_cameras(2).to(dev);
  auto opts = torch::TensorOptions().device(dev);
  CompositingSettings settings;
  settings.background = {0.1, 0.2, 0.3};
  auto m = torch::zeros({0, 3}, opts).requires_grad_(true);
  auto out = rasterize_surfels(m, torch::zeros({0, 2}, opts), torch::zeros({0, 4}, opts), torch::zeros({0, 3}, opts),
                               torch::zeros({0}, opts), cams, 20, 30, settings);
  CHECK(out.alpha.abs().max().item<float>() == 0.0f);
  CHECK((out.rgb[1][2] - 0.3f).abs().max().item<float>() < 1e-7f);
  (out.rgb.sum() + out.distortion.sum()).backward();
  CHECK(m.grad().numel() == 0);
  auto behind = torch::tensor({{0.0f, 0.0f, -2.0f}, {0.0f, 0.0f, 0.005f}}, opts).requires_grad_(true);
  auto r = rasterize_surfels(behind, torch::full({2, 2}, 0.5f, opts), torch::tensor({{1.f, 0.f, 0.f, 0.f}}, opts).repeat({2, 1}),
                             torch::ones({2, 3}, opts), torch::full({2}, 0.9f, opts), cams, 20, 30, settings);
  CHECK(r.alpha.abs().max().item<float>() == 0.0f);
  (r.rgb.sum() + r.depth.sum()).backward();
  CHECK(behind.grad().abs().max().item<float>() == 0.0f);
  auto s = flat::test::random_surfels(50, torch::kFloat, 7);
  auto nan_means = s.means.clone();
  nan_means[3][1] = std::nanf("");
  REQUIRE_THROWS_WITH(rasterize_surfels(nan_means.to(dev), s.scales.to(dev), s.rotations.to(dev), s.colors.to(dev),
                                        s.opacities.to(dev), cams, 20, 30, settings),
                      FLAT_CONTAINS("means"));
  REQUIRE_THROWS_WITH(rasterize_surfels(s.means.to(dev), -s.scales.to(dev), s.rotations.to(dev), s.colors.to(dev),
                                        s.opacities.to(dev), cams, 20, 30, settings),
                      FLAT_CONTAINS("scales"));
}
