// Packing: all frames of a scene in one safetensors file, frames.safetensors,
// for fast loading (one memory map, per-frame slices, no image decoding):
//   "images"  U8  (N,3,H,W)
//   "depth"   F32 (N,1,H,W)   when the scene has depth
//   "normals" F16 (N,3,H,W)   when the scene has normals
// Metadata: {"format": "flat-scene-pack", "version": "1", "scene": name}.
// scene.json then names the file in "packed"; the per-frame files may be kept
// or removed.
#pragma once
#include <string>

#include "flat/data/scene.h"

namespace flat::data {

inline constexpr const char* kPackFile = "frames.safetensors";

// Writes <scene>/frames.safetensors from the frame files and updates scene.json.
// With remove_frame_files the per-frame image/depth/normal files are deleted
// (after the pack and scene.json have been written).
void pack_scene(Scene& scene, bool remove_frame_files = false);

}  // namespace flat::data
