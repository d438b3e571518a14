// The anchor workload generator (flat/bench/raster_workload.h) against the
// description in ../shared/bench/raster_workload.py: counts, camera path,
// triangle shape, size, orientation and placement, and the pixel convention.
#include <cmath>

#include <torch/torch.h>

#include "flat/bench/raster_workload.h"
#include "test_support.h"

using flat::bench::anchor_camera_path;
using flat::bench::anchor_workload;

namespace {

const torch::Device kCpu(torch::kCPU);

// Rows of (N,3) unit length.
torch::Tensor unit(const torch::Tensor& x) { return x / x.norm(2, {1}, true); }

}  // namespace

TEST_CASE("anchor camera path: dolly and pan as raster_workload.py describes", "[bench]") {
  const auto path = anchor_camera_path(49, 432, 768);
  REQUIRE(path.c2w.sizes() == torch::IntArrayRef({49, 4, 4}));
  CHECK(path.focal == Approx(768.0 / (2.0 * std::tan(35.0 * M_PI / 180.0))));
  // First frame: centre (0, -0.1, -3), yaw -30 deg, pitch 5 deg down: the
  // camera's forward axis is R_y(yaw) R_x(pitch) e_z.
  const double cp = std::cos(5 * M_PI / 180), sp = std::sin(5 * M_PI / 180);
  auto expect_frame = [&](int64_t k, double yaw_deg, double cx, double cz) {
    const auto c2w = path.c2w[k];
    const double y = yaw_deg * M_PI / 180;
    CHECK(c2w[0][3].item<double>() == Approx(cx).margin(1e-6));
    CHECK(c2w[1][3].item<double>() == Approx(-0.1).margin(1e-6));
    CHECK(c2w[2][3].item<double>() == Approx(cz).margin(1e-6));
    CHECK(c2w[0][2].item<double>() == Approx(std::sin(y) * cp).margin(1e-6));
    CHECK(c2w[1][2].item<double>() == Approx(sp).margin(1e-6));
    CHECK(c2w[2][2].item<double>() == Approx(std::cos(y) * cp).margin(1e-6));
    CHECK(c2w[1][0].item<double>() == Approx(0.0).margin(1e-6));  // no roll: camera x stays horizontal
  };
  expect_frame(0, -30, 0.0, -3.0);
  expect_frame(24, 0, 0.3, -3.0 + 3.5 * 0.5);  // t = 0.5: smoothstep 0.5, sin(pi/2) = 1
  expect_frame(48, 30, 0.0, 0.5);
}

TEST_CASE("anchor workload small: counts, triangle geometry and pixel convention", "[bench]") {
  const auto w = anchor_workload("small", kCpu, 0);
  const int64_t M = 160 * 288;
  REQUIRE(w.vertices.sizes() == torch::IntArrayRef({17 * M, 3, 3}));
  REQUIRE(w.targets.size() == 17);
  CHECK(w.height == 320);
  CHECK(w.width == 576);
  CHECK(torch::isfinite(w.vertices).all().item<bool>());
  CHECK(w.opacities.min().item<double>() >= 0.3);
  CHECK(w.opacities.max().item<double>() <= 0.9);
  CHECK(torch::equal(w.sigmas, torch::ones_like(w.sigmas)));

  const auto path = anchor_camera_path(17, 320, 576);
  const double f = path.focal;
  // Frame 5's triangles: equilateral, centred where the ray through the
  // block centre leaves the room, facing that ray, circumradius 2.4 z / f.
  const int64_t k = 5;
  const auto tri = w.vertices.narrow(0, k * M, M).to(torch::kDouble);
  const auto cen = tri.mean(1);
  const auto c2w = path.c2w[k].to(torch::kDouble);
  const auto R = c2w.narrow(0, 0, 3).narrow(1, 0, 3), C = c2w.narrow(0, 0, 3).select(1, 3);
  const auto side = [&](int a, int b) { return (tri.select(1, a) - tri.select(1, b)).norm(2, {1}); };
  const auto s01 = side(0, 1), s12 = side(1, 2), s20 = side(2, 0);
  CHECK(((s01 - s12).abs() / s01).max().item<double>() < 1e-4);
  CHECK(((s01 - s20).abs() / s01).max().item<double>() < 1e-4);
  const auto cam = torch::matmul(cen - C, R);  // camera frame (R orthonormal: R^T (X - C))
  const auto z = cam.select(1, 2);
  CHECK(((s01 / std::sqrt(3.0) - 2.4 * z / f).abs() / s01).max().item<double>() < 1e-4);
  const auto normal = unit(torch::linalg_cross(tri.select(1, 1) - tri.select(1, 0), tri.select(1, 2) - tri.select(1, 0)));
  const auto ray = unit(cen - C);
  CHECK((normal * ray).sum(1).abs().min().item<double>() > 1 - 1e-5);
  // On a wall, floor or ceiling of [-3,3] x [-1.5,1.5] x [-4,4].
  const auto half = torch::tensor({3.0, 1.5, 4.0}, torch::kDouble);
  const auto gap = (cen.abs() - half).abs().amin(1);
  CHECK(gap.max().item<double>() < 1e-4);
  // Triangle (i, j) of the frame sits on the ray through block (i, j)'s
  // centre: pixel (2j + 1, 2i + 1) with pixel centres at +0.5 (our cameras).
  for (const int64_t idx : {int64_t(0), int64_t(288 * 37 + 101), M - 1}) {
    const int64_t i = idx / 288, j = idx % 288;
    const auto p = cam[idx];
    const double u = f * p[0].item<double>() / p[2].item<double>() + 576 / 2.0;
    const double v = f * p[1].item<double>() / p[2].item<double>() + 320 / 2.0;
    CHECK(u == Approx(2.0 * j + 1.0).margin(1e-3));
    CHECK(v == Approx(2.0 * i + 1.0).margin(1e-3));
  }
  // The target cameras are the path's, with the principal point at the image centre.
  CHECK(torch::allclose(w.targets.c2w[k], path.c2w[k]));
  CHECK(w.targets.intrinsics[0][0].item<double>() == Approx(f / 576.0));
  CHECK(w.targets.intrinsics[0][2].item<double>() == Approx(0.5));
}

TEST_CASE("anchor workload: the seed decides the random parts, nothing else", "[bench]") {
  const auto a = anchor_workload("small", kCpu, 0), b = anchor_workload("small", kCpu, 0);
  const auto c = anchor_workload("small", kCpu, 1);
  CHECK(torch::equal(a.vertices, b.vertices));
  CHECK(torch::equal(a.colors, b.colors));
  CHECK_FALSE(torch::equal(a.vertices, c.vertices));
  CHECK(torch::allclose(a.vertices.mean(1), c.vertices.mean(1), 1e-5, 1e-5));  // same centres, other rotations
  CHECK_FALSE(torch::equal(a.colors, c.colors));
}

TEST_CASE("anchor workload large: the Python file's sizes; an unknown case is named", "[bench]") {
  const auto w = anchor_workload("large", kCpu, 0);
  CHECK(w.vertices.size(0) == 4064256);
  CHECK(w.targets.size() == 24);
  CHECK(w.height == 432);
  CHECK(w.width == 768);
  // Targets: every other camera from index 1.
  const auto path = anchor_camera_path(49, 432, 768);
  CHECK(torch::allclose(w.targets.c2w[0], path.c2w[1]));
  CHECK(torch::allclose(w.targets.c2w[23], path.c2w[47]));
  CHECK_THROWS_WITH(anchor_workload("medium", kCpu, 0), FLAT_CONTAINS("'medium'"));
}
