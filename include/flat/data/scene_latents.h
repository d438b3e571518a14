// Precomputed latents of a scene (paper, Model Training: "For each video, we
// precompute its latents using the frozen VAE"), in <scene>/latents.safetensors:
//   "video.<i>"  (16,T',h,w) normalised VAE latent of window i
//   "camera.<i>" (32,T',h,w) RPPC camera latents of window i (E_ref ; E_dir)
//   "frames.<i>" (F,) int64 the frames window i covers, F = 1+4(T'-1)
// Metadata: format "flat-scene-latents", version, encoder "pretrained"|"random",
// weights (file name), seed, height, width. scene.json repeats this under
// "latents" (LatentInfo) so a loader can choose windows without opening the file.
#pragma once
#include <vector>

#include <ATen/ATen.h>

#include "flat/data/scene.h"

namespace flat::data {

inline constexpr const char* kLatentsFile = "latents.safetensors";

struct WindowLatents {
  at::Tensor video;   // (16,T',h,w)
  at::Tensor camera;  // (32,T',h,w)
};

// Writes latents.safetensors and records `info` (file name set here) in scene.json.
// info.windows[i] must match latents[i]: T' = 1 + (count-1)/4, h = height/8, w = width/8.
void write_scene_latents(Scene& scene, LatentInfo info, const std::vector<WindowLatents>& latents);

// Reads window i; checks shapes against scene.json and names scene and file on errors.
WindowLatents read_window_latents(const Scene& scene, size_t window);

}  // namespace flat::data
