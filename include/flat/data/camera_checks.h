// Sanity figures for imported camera paths. The optical axes of a capture
// around an object pass near a common point; the least-squares point
//   p = argmin sum_i |(I - d_i d_i^T)(p - o_i)|^2
// and the RMS distance of the axes from it check the axis convention (a wrong
// axis change makes the axes diverge or the point fall behind the cameras).
#pragma once
#include <ATen/ATen.h>

#include "flat/camera/cameras.h"

namespace flat::data {

struct AxesFocus {
  at::Tensor point;             // (3,) float64 world point nearest to all optical axes
  double rms_distance = 0;      // RMS distance of the axes from the point
  double mean_camera_distance = 0;  // mean distance of the camera centres from the point
  double in_front = 0;          // fraction of cameras that see the point in front (z > 0)
};

AxesFocus principal_axes_focus(const camera::Cameras& cameras);

}  // namespace flat::data
