// Triangle workloads for timing the rasterizer (flat_bench raster).
//
// anchor_workload: the benchmark of record, the same triangles as
// ../shared/bench/raster_workload.py (the workload the public Triangle
// Splatting rasterizer was timed on): one camera-facing equilateral triangle
// per 2x2 pixel block of every frame of a dolly-and-pan through a box room,
// rendered into a subset of those cameras. Same torch operations in the same
// order and the same generator calls, so on the same device and torch
// version the vertices match the Python file's (flat_bench raster
// --write-workload writes them for a comparison).
//
// room_workload: our older synthetic "decoded scene" (a 180-degree pan in a
// box room, triangles parallel to the image plane), kept for continuity with
// the earlier rows of docs/benchmarks.md.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"

namespace flat::bench {

struct RasterWorkload {
  std::string name;
  at::Tensor vertices;   // (N,3,3) world
  at::Tensor colors;     // (N,3)
  at::Tensor opacities;  // (N)
  at::Tensor sigmas;     // (N)
  camera::Cameras targets;  // the views to render
  int64_t height = 0, width = 0;
};

// The Python file's CASES: "large" (49 frames 432x768, targets 1,3,...,47:
// 4,064,256 triangles, 24 views) and "small" (17 frames 320x576, all 17
// targets: 783,360 triangles). Throws naming the case when unknown.
RasterWorkload anchor_workload(const std::string& which, const at::Device& device, uint64_t seed = 0);

// Its camera path: c2w (n,4,4) float32 and the focal length in pixels (fovx 70 degrees).
struct AnchorCameraPath {
  at::Tensor c2w;
  double focal = 0;
};
AnchorCameraPath anchor_camera_path(int64_t frames, int64_t height, int64_t width);

// frames cameras panning 180 degrees about the centre of an 8 x 3 x 8 m room,
// one triangle of inradius ~1 px per 2x2 block of each frame on the walls,
// target_views of them evenly spaced as targets.
RasterWorkload room_workload(const std::string& name, int64_t frames, int64_t height, int64_t width,
                             int64_t target_views, const at::Device& device);

}  // namespace flat::bench
