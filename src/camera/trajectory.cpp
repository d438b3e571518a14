#include "flat/camera/trajectory.h"

#include <cmath>

#include "flat/core/error.h"

namespace flat::camera {

namespace {

// Rotation of angle a (radians) about the unit axis u (Rodrigues), (3,3) double.
at::Tensor axis_rotation(const at::Tensor& u, double a) {
  auto K = at::zeros({3, 3}, at::kDouble);
  K[0][1] = -u[2];
  K[0][2] = u[1];
  K[1][0] = u[2];
  K[1][2] = -u[0];
  K[2][0] = -u[1];
  K[2][1] = u[0];
  return at::eye(3, at::kDouble) + std::sin(a) * K + (1 - std::cos(a)) * K.matmul(K);
}

}  // namespace

Cameras make_trajectory(const Cameras& anchor, double look_distance, const TrajectorySpec& spec) {
  FLAT_CHECK(anchor.intrinsics.defined() && anchor.size() >= 1, "trajectory: no anchor camera");
  FLAT_CHECK(spec.frames >= 2, "trajectory: frames must be >= 2, got " + std::to_string(spec.frames));
  FLAT_CHECK(std::isfinite(look_distance) && look_distance > 0,
             "trajectory: the look-at distance must be a positive number, got " + std::to_string(look_distance));
  FLAT_CHECK(spec.preset == "orbit" || spec.preset == "dolly",
             "trajectory: unknown preset '" + spec.preset + "' (orbit | dolly)");
  const auto c2w0 = anchor.c2w[0].to(at::kCPU, at::kDouble);
  const auto R0 = c2w0.slice(0, 0, 3).slice(1, 0, 3);
  const auto p0 = c2w0.slice(0, 0, 3).select(1, 3);
  const auto forward = R0.select(1, 2), up = -R0.select(1, 1);  // OpenCV: +z forward, -y up
  const auto target = p0 + look_distance * forward;

  std::vector<at::Tensor> poses;
  for (int64_t i = 0; i < spec.frames; ++i) {
    // s goes 0 -> 1 -> 0 -> -1 -> 0 over the frames (one smooth loop).
    const double s = std::sin(2 * M_PI * double(i) / double(spec.frames));
    auto c2w = at::eye(4, at::kDouble);
    if (spec.preset == "orbit") {
      auto R = axis_rotation(up, s * spec.degrees * M_PI / 180.0);
      c2w.slice(0, 0, 3).slice(1, 0, 3).copy_(R.matmul(R0));
      c2w.slice(0, 0, 3).select(1, 3).copy_(target + R.matmul(p0 - target));
    } else {
      // Dolly in and back once over the frames: 0 -> fraction -> 0 of the look distance.
      const double t = std::sin(M_PI * double(i) / double(spec.frames)) * spec.fraction * look_distance;
      c2w.slice(0, 0, 3).slice(1, 0, 3).copy_(R0);
      c2w.slice(0, 0, 3).select(1, 3).copy_(p0 + t * forward);
    }
    poses.push_back(c2w);
  }
  Cameras out{anchor.intrinsics[0].to(at::kCPU, at::kFloat).unsqueeze(0).expand({spec.frames, 4}).contiguous(),
              at::stack(poses).to(at::kFloat)};
  out.check("trajectory '" + spec.preset + "'");
  return out;
}

}  // namespace flat::camera
