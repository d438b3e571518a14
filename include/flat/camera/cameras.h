// A batch of pinhole cameras at one resolution, OpenCV convention
// (x right, y down, z forward), intrinsics normalised by the image size so the
// same cameras serve every resolution.
#pragma once
#include <cstdint>
#include <string>

#include <ATen/ATen.h>

namespace flat::camera {

struct Cameras {
  // (V,4) float32: fx/W, fy/H, cx/W, cy/H (pixel-centre convention: a pixel
  // (u,v) has its centre at (u+0.5, v+0.5) in pixel units).
  at::Tensor intrinsics;
  // (V,4,4) float32 camera-to-world, rigid, OpenCV axes.
  at::Tensor c2w;

  int64_t size() const { return intrinsics.size(0); }
  // Throws flat::Error naming `what` on wrong shapes, dtypes or non-finite values.
  void check(const std::string& what) const;
  Cameras to(const at::Device& device) const;
  Cameras index(const at::Tensor& indices) const;  // select cameras by (K,) int64 index
};

// Intrinsics in pixels (V,4): fx, fy, cx, cy for an H x W image.
at::Tensor pixel_intrinsics(const at::Tensor& normalised, int64_t height, int64_t width);
// Inverse of normalised -> pixel.
at::Tensor normalise_intrinsics(const at::Tensor& pixels, int64_t height, int64_t width);

// Rigid inverse of (V,4,4) camera-to-world: world-to-camera.
at::Tensor world_to_camera(const at::Tensor& c2w);

}  // namespace flat::camera
