// Novel-view trajectory presets: geometry of orbit and dolly.
#include "flat/camera/trajectory.h"
#include "test_support.h"

using namespace flat;

namespace {
camera::Cameras anchor() {
  // Camera at (1,2,3) looking along world +x (OpenCV: z forward = +x, y down = -z).
  auto c2w = at::eye(4);
  c2w.slice(0, 0, 3).slice(1, 0, 3).copy_(at::tensor({0.f, 0.f, 1.f, -1.f, 0.f, 0.f, 0.f, -1.f, 0.f}).view({3, 3}));
  c2w[0][3] = 1;
  c2w[1][3] = 2;
  c2w[2][3] = 3;
  return {at::tensor({0.8f, 1.2f, 0.5f, 0.5f}).unsqueeze(0), c2w.unsqueeze(0)};
}
}  // namespace

TEST_CASE("orbit: every camera keeps its distance to the target and looks at it", "[camera]") {
  camera::TrajectorySpec spec;
  spec.frames = 16;
  spec.degrees = 30;
  auto cams = camera::make_trajectory(anchor(), 4.0, spec);
  REQUIRE(cams.size() == 16);
  const auto target = at::tensor({5.f, 2.f, 3.f});
  CHECK(test::rel_error(cams.c2w[0], anchor().c2w[0]) < 1e-6);  // starts at the anchor
  double max_angle = 0;
  for (int64_t i = 0; i < 16; ++i) {
    auto p = cams.c2w[i].slice(0, 0, 3).select(1, 3);
    auto f = cams.c2w[i].slice(0, 0, 3).select(1, 2);
    auto to_target = target - p;
    CHECK(to_target.norm().item<double>() == Approx(4.0).epsilon(1e-5));
    CHECK((to_target / to_target.norm()).dot(f).item<double>() == Approx(1.0).epsilon(1e-5));
    CHECK(p[2].item<double>() == Approx(3.0).margin(1e-5));  // circles about the up axis (world z)
    max_angle = std::max(max_angle, std::acos(std::clamp(f[0].item<double>(), -1.0, 1.0)) * 180 / M_PI);
  }
  CHECK(max_angle == Approx(30.0).margin(1.5));  // sampled at 16 steps: the peak is hit (sin = 1 at i = 4)
  CHECK(test::rel_error(cams.intrinsics, anchor().intrinsics.expand({16, 4})) < 1e-7);
}

TEST_CASE("dolly: moves along the optical axis towards the target and back, orientation fixed", "[camera]") {
  camera::TrajectorySpec spec;
  spec.preset = "dolly";
  spec.frames = 8;
  spec.fraction = 0.5;
  auto cams = camera::make_trajectory(anchor(), 4.0, spec);
  for (int64_t i = 0; i < 8; ++i) {
    auto p = cams.c2w[i].slice(0, 0, 3).select(1, 3);
    CHECK(test::rel_error(cams.c2w[i].slice(0, 0, 3).slice(1, 0, 3), anchor().c2w[0].slice(0, 0, 3).slice(1, 0, 3)) <
          1e-6);
    CHECK(p[1].item<double>() == Approx(2.0).margin(1e-6));
    CHECK(p[0].item<double>() >= 1.0 - 1e-6);
    CHECK(p[0].item<double>() <= 3.0 + 1e-6);
  }
  CHECK(cams.c2w[4][0][3].item<double>() == Approx(3.0).epsilon(1e-6));  // furthest: 0.5 * 4 m in, half-way
  // In and back once (not twice): closer every frame up to the middle, then back every frame.
  for (int64_t i = 1; i < 8; ++i) {
    const double step = cams.c2w[i][0][3].item<double>() - cams.c2w[i - 1][0][3].item<double>();
    INFO("frame " << i);
    if (i <= 4) CHECK(step > 0);
    else CHECK(step < 0);
  }
}

TEST_CASE("trajectory: bad specs are refused with their value", "[camera]") {
  camera::TrajectorySpec spec;
  spec.preset = "spiral";
  REQUIRE_THROWS_WITH(camera::make_trajectory(anchor(), 4.0, spec), FLAT_CONTAINS("spiral"));
  spec.preset = "orbit";
  REQUIRE_THROWS_WITH(camera::make_trajectory(anchor(), -1.0, spec), FLAT_CONTAINS("distance"));
  spec.frames = 1;
  REQUIRE_THROWS_WITH(camera::make_trajectory(anchor(), 4.0, spec), FLAT_CONTAINS("frames"));
}
