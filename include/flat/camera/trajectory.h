// Novel-view trajectories for flat_infer (paper: the generated scenes are
// explored along camera paths other than the input's): presets built around
// one anchor camera and the distance to what it looks at.
//
//   orbit: the camera circles the look-at point (anchor position + distance
//          along its optical axis) about the anchor's up axis, sweeping
//          +-degrees and back, always looking at that point;
//   dolly: the camera moves along its optical axis towards the look-at point
//          by fraction x distance and back, keeping its orientation.
//
// Frames go out and back (a loop), so a video of them repeats smoothly.
#pragma once
#include <cstdint>
#include <string>

#include "flat/camera/cameras.h"

namespace flat::camera {

struct TrajectorySpec {
  std::string preset = "orbit";  // orbit | dolly
  int64_t frames = 48;
  double degrees = 20;    // orbit: half the sweep
  double fraction = 0.4;  // dolly: share of the look-at distance travelled
};

// anchor: one camera (index 0 of `anchor` is used); look_distance > 0 in
// metres. Intrinsics are the anchor's. Throws flat::Error on a bad spec.
Cameras make_trajectory(const Cameras& anchor, double look_distance, const TrajectorySpec& spec);

}  // namespace flat::camera
