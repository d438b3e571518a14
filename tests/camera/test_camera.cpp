#include <cmath>

#include "flat/camera/ray_embeddings.h"
#include "flat/core/autocast_scope.h"
#include "flat/core/error.h"
#include "primitives/primitive_cameras.h"
#include "test_support.h"

using namespace flat::camera;

namespace {
Cameras one_camera(double fx, double fy, double cx, double cy, at::Tensor c2w) {
  return {at::tensor({fx, fy, cx, cy}, at::kDouble).view({1, 4}), c2w.to(at::kDouble).view({1, 4, 4})};
}
}  // namespace

TEST_CASE("pixel rays go through pixel centres (OpenCV convention)", "[camera]") {
  // 4x2 image (W=4, H=2), fx=fy=2 px, principal point at the image centre.
  auto cams = one_camera(2.0 / 4, 2.0 / 2, 2.0 / 4, 1.0 / 2, at::eye(4, at::kDouble));
  auto rays = pixel_rays(cams, 2, 4);
  REQUIRE(rays.directions.sizes() == at::IntArrayRef({1, 2, 4, 3}));
  // pixel (u=0, v=0): centre (0.5, 0.5) -> ((0.5-2)/2, (0.5-1)/2, 1) = (-0.75, -0.25, 1)
  auto d = rays.directions[0][0][0];
  double n = std::sqrt(0.75 * 0.75 + 0.25 * 0.25 + 1.0);
  CHECK(d[0].item<double>() == Approx(-0.75 / n));
  CHECK(d[1].item<double>() == Approx(-0.25 / n));
  CHECK(d[2].item<double>() == Approx(1.0 / n));
}

TEST_CASE("rays rotate and translate with the camera-to-world", "[camera]") {
  // Camera at (1,2,3) rotated 90 degrees about y: camera z -> world x.
  auto c2w = at::eye(4, at::kDouble);
  c2w[0][0] = 0; c2w[0][2] = 1; c2w[2][0] = -1; c2w[2][2] = 0;
  c2w[0][3] = 1; c2w[1][3] = 2; c2w[2][3] = 3;
  auto cams = one_camera(1.0, 1.0, 0.5, 0.5, c2w);
  auto rays = pixel_rays(cams, 1, 1);  // the single pixel looks straight ahead
  auto d = rays.directions.view({3});
  CHECK(d[0].item<double>() == Approx(1.0));
  CHECK(std::abs(d[1].item<double>()) < 1e-12);
  CHECK(std::abs(d[2].item<double>()) < 1e-12);
  CHECK(rays.origins.view({3})[1].item<double>() == Approx(2.0));
}

TEST_CASE("RPPC and Plucker equal hand-computed values", "[camera]") {
  // Hand-picked rays: o=(1,2,3), d=(0,0,1); o=(0,1,0), d=(1,0,0); o=(2,0,0), d=(0,0.6,0.8)
  auto o = at::tensor({1., 2., 3., 0., 1., 0., 2., 0., 0.}, at::kDouble).view({1, 1, 3, 3});
  auto d = at::tensor({0., 0., 1., 1., 0., 0., 0., .6, .8}, at::kDouble).view({1, 1, 3, 3});
  Rays rays{o, d};
  auto pl = plucker_map(rays);  // (1,6,1,3)
  auto rp = rppc_map(rays);
  REQUIRE(pl.sizes() == at::IntArrayRef({1, 6, 1, 3}));
  // Plucker moment o x d: (1,2,3)x(0,0,1) = (2,-1,0); (0,1,0)x(1,0,0) = (0,0,-1); (2,0,0)x(0,.6,.8) = (0,-1.6,1.2)
  double moment[3][3] = {{2, -1, 0}, {0, 0, -1}, {0, -1.6, 1.2}};
  // RPPC closest point o-(o.d)d: (1,2,3)-3(0,0,1) = (1,2,0); (0,1,0)-0 = (0,1,0); (2,0,0)-0 = (2,0,0)
  double closest[3][3] = {{1, 2, 0}, {0, 1, 0}, {2, 0, 0}};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      CHECK(pl[0][c][0][r].item<double>() == Approx(moment[r][c]).margin(1e-12));
      CHECK(rp[0][c][0][r].item<double>() == Approx(closest[r][c]).margin(1e-12));
      CHECK(pl[0][c + 3][0][r].item<double>() == d[0][0][r][c].item<double>());
      CHECK(rp[0][c + 3][0][r].item<double>() == d[0][0][r][c].item<double>());
    }
}

TEST_CASE("half-resolution rays are the 2x2 block-centre rays", "[camera]") {
  auto cams = one_camera(0.9, 1.2, 0.47, 0.53, at::eye(4, at::kDouble));
  auto full = pixel_rays(cams, 8, 12).directions;  // (1,8,12,3)
  auto half = pixel_rays(cams, 4, 6).directions;
  // Block (i,j) centre lies at full-res pixel position (2j+1, 2i+1): the average
  // of the four camera-plane points, i.e. the ray through their mean.
  auto planar = full / full.select(-1, 2).unsqueeze(-1);
  auto block = planar.view({1, 4, 2, 6, 2, 3}).mean({2, 4});
  block = block / block.norm(2, -1, true);
  CHECK(flat::test::rel_error(half, block) < 1e-12);
}

TEST_CASE("camera checks name the problem", "[camera]") {
  Cameras bad{at::zeros({2, 3}), at::zeros({2, 4, 4})};
  REQUIRE_THROWS_WITH(bad.check("scene x"), FLAT_CONTAINS("scene x intrinsics") && FLAT_CONTAINS("(2,3)"));
  Cameras nan{at::ones({1, 4}), at::full({1, 4, 4}, NAN)};
  REQUIRE_THROWS_WITH(nan.check("cams"), FLAT_CONTAINS("non-finite"));
}

TEST_CASE("bf16 autocast leaves pixel rays and world-to-camera in fp32", "[camera]") {
  // The rays feed the triangle geometry inside the training step's bf16
  // autocast; an einsum / matmul there would be cast to bf16 (~3 digits).
  const Cameras cams = flat::test::make_cameras(3);  // varied rotations, positions, intrinsics
  auto plain = pixel_rays(cams, 6, 8);
  auto plain_w2c = world_to_camera(cams.c2w);
  Rays mixed;
  at::Tensor mixed_w2c;
  {
    flat::AutocastScope autocast(true, at::kCPU);
    REQUIRE(at::matmul(at::ones({2, 2}), at::ones({2, 2})).scalar_type() == at::kBFloat16);
    mixed = pixel_rays(cams, 6, 8);
    mixed_w2c = world_to_camera(cams.c2w);
  }
  CHECK(mixed.directions.scalar_type() == at::kFloat);
  const double ed = flat::test::rel_error(mixed.directions, plain.directions);
  const double ew = flat::test::rel_error(mixed_w2c, plain_w2c);
  INFO("relative error under autocast: directions " << ed << ", world-to-camera " << ew);
  CHECK(ed < 1e-5);
  CHECK(ew < 1e-5);
  // and both against the fp64 reference
  const Cameras fp64 = flat::test::make_cameras(3, at::kDouble);
  auto ref = pixel_rays(fp64, 6, 8);
  CHECK(flat::test::rel_error(mixed.directions, ref.directions) < 1e-5);
  CHECK(flat::test::rel_error(mixed_w2c, world_to_camera(fp64.c2w)) < 1e-5);
}
