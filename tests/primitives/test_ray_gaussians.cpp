// Pixel-aligned Gaussians (3DGS / 2DGS baselines): placed as the triangles
// (mean on the anchor ray at depth D), one standard deviation projecting to
// init_scale pixels at zero output, axes = the ray frame at zero rotation
// (a surfel's normal along its ray), gradients; the scene container and the
// ellipse fans the GLB and viewer draw.
#include <cmath>

#include "flat/camera/rays.h"
#include "flat/core/autocast_scope.h"
#include "flat/core/error.h"
#include "flat/model/output_heads.h"
#include "flat/primitives/head_channels.h"
#include "flat/primitives/ray_gaussians.h"
#include "flat/primitives/scene_primitives.h"
#include "flat/primitives/splat_ellipses.h"
#include "primitive_cameras.h"
#include "test_support.h"

using namespace flat::primitives;
using flat::test::make_cameras;

namespace {

constexpr int64_t B = 2, T = 2, H = 12, W = 16;

// Rotation matrix of unit quaternions (w,x,y,z), written out here so the test
// does not share the code under test.
at::Tensor rotation_of(const at::Tensor& q) {
  auto w = q.select(-1, 0), x = q.select(-1, 1), y = q.select(-1, 2), z = q.select(-1, 3);
  return at::stack({1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y), 2 * (x * y + w * z),
                    1 - 2 * (x * x + z * z), 2 * (y * z - w * x), 2 * (x * z - w * y), 2 * (y * z + w * x),
                    1 - 2 * (x * x + y * y)},
                   -1)
      .unflatten(-1, {3, 3});
}

}  // namespace

TEST_CASE("gaussian channel layouts: 12 (3DGS) and 11 (2DGS) channels, no sigma", "[primitives]") {
  auto g3 = gaussian_channels(3), g2 = gaussian_channels(2);
  CHECK(g3.total == 12);
  CHECK(g2.total == 11);
  CHECK(g3.sigma == -1);
  CHECK(g2.rotation == 3);
  CHECK(g2.colour == 7);
  CHECK(g2.opacity == 10);
  auto groups = flat::model::head_groups(g2);
  REQUIRE(groups.size() == 5);
  CHECK(groups[1].first == "scale");
  CHECK(groups[1].second.count == 2);
  CHECK(flat::model::head_groups(triangle_channels("ray_centred")).size() == 6);
  REQUIRE_THROWS_WITH(gaussian_channels(4), FLAT_CONTAINS("3 (3DGS) or 2 (2DGS)"));
}

TEST_CASE("build_gaussians at zero output: means on the anchor rays, one sigma = init_scale px, ray-frame axes",
          "[primitives]") {
  auto cams = make_cameras(B * T, at::kDouble);
  TriangleParamConfig cfg;
  cfg.depth_activation = "exp";
  cfg.depth_init = 3.0;
  cfg.init_scale = 0.8;
  for (int64_t k : {3, 2}) {
    auto raw = at::zeros({B, gaussian_channels(k).total, T, H / 2, W / 2}, at::kDouble);
    auto g = build_gaussians(raw, cams, H, W, cfg, k);
    REQUIRE(g.means.sizes() == at::IntArrayRef({B, T * H / 2 * W / 2, 3}));
    REQUIRE(g.scales.size(-1) == k);
    auto rays = flat::camera::pixel_rays(cams, H / 2, W / 2);
    auto o = rays.origins.reshape({B, -1, 3}), d = rays.directions.reshape({B, -1, 3});
    CHECK(flat::test::rel_error(g.means, o + 3.0 * d) < 1e-12);
    // Axes: third column = the ray direction, first = perpendicular to it.
    auto R = rotation_of(g.rotations);
    CHECK((R.select(-1, 2) - d).abs().max().item<double>() < 1e-9);
    CHECK((R.select(-1, 0) * d).sum(-1).abs().max().item<double>() < 1e-9);
    CHECK((g.rotations.norm(2, -1) - 1).abs().max().item<double>() < 1e-12);
    // Every axis at the same scale; projected through the token's camera, a
    // tangent step of one sigma moves the mean by >= init_scale pixels, and
    // exactly that along the least-stretched direction (to first order).
    CHECK((g.scales - g.scales.select(-1, 0).unsqueeze(-1)).abs().max().item<double>() < 1e-12);
    auto Kpx = flat::camera::pixel_intrinsics(cams.intrinsics, H, W);
    auto w2c = flat::camera::world_to_camera(cams.c2w);
    const int64_t per = H / 2 * W / 2;
    for (int64_t b = 0; b < B; ++b)
      for (int64_t n : {int64_t(0), per + 7}) {  // a token of frame 0 and one of frame 1
        const int64_t cam = b * T + n / per;
        auto project = [&](const at::Tensor& p) {
          auto c = at::matmul(w2c[cam].narrow(0, 0, 3).narrow(1, 0, 3), p) + w2c[cam].narrow(0, 0, 3).select(1, 3);
          return at::stack({Kpx[cam][0] * c[0] / c[2], Kpx[cam][1] * c[1] / c[2]});
        };
        const auto mu = g.means[b][n];
        const double s = g.scales[b][n][0].item<double>();
        double least = INFINITY;
        for (int a = 0; a < 16; ++a) {
          const double t = M_PI * a / 16;
          auto dir = std::cos(t) * R[b][n].select(1, 0) + std::sin(t) * R[b][n].select(1, 1);
          auto step = (project(mu + 1e-4 * s * dir) - project(mu)) / 1e-4;
          least = std::min(least, step.norm().item<double>());
        }
        CHECK(least == Approx(0.8).epsilon(0.02));
      }
  }
}

TEST_CASE("build_gaussians: every output differentiable, matching finite differences", "[primitives]") {
  auto cams = make_cameras(B * T, at::kDouble);
  TriangleParamConfig cfg;
  auto gen = at::make_generator<at::CPUGeneratorImpl>(3);
  auto raw = (0.5 * at::randn({B, gaussian_channels(2).total, T, H / 2, W / 2}, gen, at::kDouble)).requires_grad_(true);
  auto probe = [&](const at::Tensor& x) {
    auto g = build_gaussians(x, cams, H, W, cfg, 2);
    return g.means.sum() * 0.3 + g.scales.log().sum() + (g.rotations * at::arange(4, at::kDouble)).sum() +
           g.colors.sum() - g.opacities.sum() * 2;
  };
  auto f = probe(raw);
  auto grad = torch::autograd::grad({f}, {raw})[0];
  auto flat_raw = raw.detach().flatten();
  for (int64_t i : {int64_t(0), int64_t(97), int64_t(raw.numel() / 2 + 5), int64_t(raw.numel() - 1)}) {
    auto plus = flat_raw.clone(), minus = flat_raw.clone();
    plus[i] += 1e-6;
    minus[i] -= 1e-6;
    const double fd = (probe(plus.view_as(raw)).item<double>() - probe(minus.view_as(raw)).item<double>()) / 2e-6;
    CHECK(grad.flatten()[i].item<double>() == Approx(fd).margin(1e-6).epsilon(1e-5));
  }
  CHECK(grad.abs().gt(0).to(at::kDouble).mean().item<double>() > 0.9);  // every channel reaches the outputs
}

TEST_CASE("build_gaussians rejects SH colour and a wrong channel count", "[primitives]") {
  auto cams = make_cameras(B * T);
  TriangleParamConfig cfg;
  REQUIRE_THROWS_WITH(build_gaussians(at::zeros({B, 12, T, H / 2, W / 2}), cams, H, W, cfg, 2),
                      FLAT_CONTAINS("(B,11,T,H/2,W/2)"));
  cfg.colour_activation = "sh";
  cfg.sh_degree = 1;
  REQUIRE_THROWS_WITH(build_gaussians(at::zeros({B, 12, T, H / 2, W / 2}), cams, H, W, cfg, 3),
                      FLAT_CONTAINS("triangles only"));
}

TEST_CASE("ScenePrimitives: one interface over triangles and Gaussians", "[primitives]") {
  GaussianSoup g{at::rand({2, 5, 3}), at::rand({2, 5, 2}) + 0.1, at::rand({2, 5, 4}), at::rand({2, 5, 3}),
                 at::rand({2, 5})};
  auto s = ScenePrimitives::of(g);
  CHECK(s.representation == kSurfels2d);
  CHECK(s.batch() == 2);
  CHECK(s.size() == 5);
  auto one = s.scene(1);
  CHECK(one.gaussians.means.equal(g.means[1]));
  CHECK(one.centres().equal(g.means[1]));
  auto names = one.named_tensors();
  REQUIRE(names.size() == 5);
  CHECK(names[1].first == "scales");
  auto kept = one.index_select(at::tensor({4, 0}, at::kLong));
  CHECK(kept.gaussians.opacities.equal(at::stack({g.opacities[1][4], g.opacities[1][0]})));
  auto joined = cat({s, s}, 1);
  CHECK(joined.size() == 10);
  CHECK(joined.gaussians.scales.narrow(1, 5, 5).equal(g.scales));
  REQUIRE_THROWS_WITH(s.with_tensors({g.means}), FLAT_CONTAINS("needs 5 tensors"));
  TriangleSoup t{at::rand({1, 4, 3, 3}), at::rand({1, 4, 3}), at::rand({1, 4}), at::rand({1, 4})};
  auto ts = ScenePrimitives::of(t);
  CHECK(ts.is_triangles());
  CHECK(ts.centres().allclose(t.vertices.mean(-2)));
  REQUIRE_THROWS_WITH(cat({ts, s}, 1), FLAT_CONTAINS("mixed representations"));
  CHECK(ScenePrimitives::of(GaussianSoup{g.means, at::ones({2, 5, 3}), g.rotations, g.colors, g.opacities})
            .representation == kGaussians3d);
}

TEST_CASE("splat_ellipses: fans on the 1.5-sigma ellipse of the two largest axes", "[primitives]") {
  // Gaussian 0: axis-aligned, scales (0.5, 2, 1) -> ellipse axes y (2) and z (1).
  // Gaussian 1: a surfel rotated 90 degrees about z, scales (3, 1).
  const double c = std::sqrt(0.5);
  GaussianSoup g3{at::tensor({1.0, 2.0, 3.0}).view({1, 3}), at::tensor({0.5, 2.0, 1.0}).view({1, 3}),
                  at::tensor({1.0, 0.0, 0.0, 0.0}).view({1, 4}), at::tensor({0.2, 0.4, 0.6}).view({1, 3}),
                  at::tensor({0.7})};
  auto t = splat_ellipses(g3, 8);
  REQUIRE(t.vertices.sizes() == at::IntArrayRef({8, 3, 3}));
  auto rim = t.vertices.select(1, 1) - at::tensor({1.0, 2.0, 3.0});  // (8,3)
  CHECK(rim.select(1, 0).abs().max().item<double>() < 1e-6);          // in the y-z plane
  auto e = (rim.select(1, 1) / 3.0).pow(2) + (rim.select(1, 2) / 1.5).pow(2);
  CHECK((e - 1).abs().max().item<double>() < 1e-5);
  CHECK(t.vertices.select(1, 0).sub(at::tensor({1.0, 2.0, 3.0})).abs().max().item<double>() < 1e-6);
  CHECK(t.colors[5].allclose(at::tensor({0.2, 0.4, 0.6})));
  CHECK(t.opacities.allclose(at::full({8}, 0.7, at::kDouble)));
  GaussianSoup g2{at::zeros({1, 3}, at::kDouble), at::tensor({3.0, 1.0}).view({1, 2}),
                  at::tensor({c, 0.0, 0.0, c}).view({1, 4}), at::ones({1, 3}, at::kDouble), at::ones({1}, at::kDouble)};
  auto s = splat_ellipses(g2, 6).vertices.select(1, 1);  // (6,3): the rotated x axis is world y
  CHECK(s.select(1, 2).abs().max().item<double>() < 1e-6);
  CHECK(((s.select(1, 1) / 4.5).pow(2) + (s.select(1, 0) / 1.5).pow(2) - 1).abs().max().item<double>() < 1e-5);
}

TEST_CASE("bf16 autocast leaves the Gaussians' means and rotations in fp32", "[primitives]") {
  // As the triangles (test_ray_triangles.cpp): the anchor rays and frames are
  // fp32 geometry even inside the training step's bf16 autocast.
  auto cams = make_cameras(B * T);
  auto gen = at::make_generator<at::CPUGeneratorImpl>(29);
  TriangleParamConfig cfg;
  auto raw = at::randn({B, gaussian_channels(3).total, T, H / 2, W / 2}, gen, at::kFloat);
  auto plain = build_gaussians(raw, cams, H, W, cfg, 3);
  GaussianSoup mixed;
  {
    flat::AutocastScope autocast(true, at::kCPU);
    REQUIRE(at::matmul(at::ones({2, 2}), at::ones({2, 2})).scalar_type() == at::kBFloat16);
    mixed = build_gaussians(raw, cams, H, W, cfg, 3);
  }
  const double em = flat::test::rel_error(mixed.means, plain.means);
  const double er = flat::test::rel_error(mixed.rotations, plain.rotations);
  INFO("relative error under autocast: means " << em << ", rotations " << er);
  CHECK(em < 1e-5);
  CHECK(er < 1e-5);
}
