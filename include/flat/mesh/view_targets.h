// The images a scene is fitted to by the post-optimisation and the mesh
// conversion (refine.h, opaque_conversion.h): V views with their cameras,
// and the depth / normals of the views when the scene has them.
#pragma once
#include <cstdint>
#include <string>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"

namespace flat::mesh {

struct ViewTargets {
  at::Tensor rgb;            // (V,3,H,W) float32 in [0,1]
  at::Tensor depth;          // (V,1,H,W) metric z-depth, 0 = invalid; or undefined
  at::Tensor normals;        // (V,3,H,W) camera-space; or undefined
  camera::Cameras cameras;   // V cameras

  int64_t size() const { return rgb.size(0); }
  int64_t height() const { return rgb.size(2); }
  int64_t width() const { return rgb.size(3); }
  ViewTargets to(const at::Device& device) const;
  ViewTargets index(const at::Tensor& views) const;  // (K,) int64
  // Throws flat::Error naming `what` and the part at fault (shapes, NaN, counts).
  void check(const std::string& what) const;
};

}  // namespace flat::mesh
