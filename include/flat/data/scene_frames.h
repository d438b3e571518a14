// Loads selected frames of a scene (RGB, and depth/normals when asked) from its
// per-frame files or, when the scene is packed, from slices of the memory-mapped
// frames.safetensors (no OpenImageIO needed). Errors name the scene and file.
#pragma once
#include <cstdint>
#include <vector>

#include <ATen/ATen.h>

#include "flat/data/scene.h"

namespace flat::data {

struct FrameBatch {
  at::Tensor images;   // (K,3,H,W) float32 in [0,1]
  at::Tensor depth;    // (K,1,H,W) float32 metric z-depth (0 = invalid), or undefined
  at::Tensor normals;  // (K,3,H,W) float32 camera-space, or undefined
};

FrameBatch load_frames(const Scene& scene, const std::vector<int64_t>& indices, bool want_depth, bool want_normals);

}  // namespace flat::data
