#include "flat/camera/trajectory.h"

#include <cmath>

#include <glm/gtc/matrix_transform.hpp>
#include <glm/mat3x3.hpp>
#include <glm/vec3.hpp>

#include "flat/core/error.h"

namespace flat::camera {

namespace {

// (4,4) row-major camera-to-world tensor <-> GLM's column-major rotation and
// position (small fixed-size maths on the host is GLM's).
void read_pose(const at::Tensor& c2w, glm::dmat3& R, glm::dvec3& p) {
  const auto a = c2w.to(at::kCPU, at::kDouble).contiguous();
  const double* m = a.data_ptr<double>();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) R[c][r] = m[4 * r + c];
    p[r] = m[4 * r + 3];
  }
}

at::Tensor pose_tensor(const glm::dmat3& R, const glm::dvec3& p) {
  auto t = at::eye(4, at::kDouble);
  double* m = t.data_ptr<double>();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m[4 * r + c] = R[c][r];
    m[4 * r + 3] = p[r];
  }
  return t;
}

}  // namespace

Cameras make_trajectory(const Cameras& anchor, double look_distance, const TrajectorySpec& spec) {
  FLAT_CHECK(anchor.intrinsics.defined() && anchor.size() >= 1, "trajectory: no anchor camera");
  FLAT_CHECK(spec.frames >= 2, "trajectory: frames must be >= 2, got " + std::to_string(spec.frames));
  FLAT_CHECK(std::isfinite(look_distance) && look_distance > 0,
             "trajectory: the look-at distance must be a positive number, got " + std::to_string(look_distance));
  FLAT_CHECK(spec.preset == "orbit" || spec.preset == "dolly",
             "trajectory: unknown preset '" + spec.preset + "' (orbit | dolly)");
  glm::dmat3 R0;
  glm::dvec3 p0;
  read_pose(anchor.c2w[0], R0, p0);
  const glm::dvec3 forward = R0[2], up = -R0[1];  // OpenCV: +z forward, -y up
  const glm::dvec3 target = p0 + look_distance * forward;

  std::vector<at::Tensor> poses;
  for (int64_t i = 0; i < spec.frames; ++i) {
    // s goes 0 -> 1 -> 0 -> -1 -> 0 over the frames (one smooth loop).
    const double s = std::sin(2 * M_PI * double(i) / double(spec.frames));
    if (spec.preset == "orbit") {
      // About the up axis through the target (Rodrigues, as glm::rotate).
      const glm::dmat3 R = glm::dmat3(glm::rotate(glm::dmat4(1.0), s * spec.degrees * M_PI / 180.0, up));
      poses.push_back(pose_tensor(R * R0, target + R * (p0 - target)));
    } else {
      // Dolly in and back once over the frames: 0 -> fraction -> 0 of the look distance.
      const double t = std::sin(M_PI * double(i) / double(spec.frames)) * spec.fraction * look_distance;
      poses.push_back(pose_tensor(R0, p0 + t * forward));
    }
  }
  Cameras out{anchor.intrinsics[0].to(at::kCPU, at::kFloat).unsqueeze(0).expand({spec.frames, 4}).contiguous(),
              at::stack(poses).to(at::kFloat)};
  out.check("trajectory '" + spec.preset + "'");
  return out;
}

}  // namespace flat::camera
