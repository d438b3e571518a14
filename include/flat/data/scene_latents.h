// Precomputed latents of a scene (paper, Model Training: "For each video, we
// precompute its latents using the frozen VAE"), in <scene>/latents.safetensors:
//   "video.<i>"  (16,T',h,w) normalised VAE latent of window i
//   "camera.<i>" (32,T',h,w) RPPC camera latents of window i (E_ref ; E_dir)
//   "camera_plucker.<i>" (32,T',h,w) optional: Plucker camera latents (the
//                conditioning ablation; flat_latents --camera-rays rppc,plucker)
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
  at::Tensor camera_plucker;  // (32,T',h,w) or undefined (written only when asked for)
};

// Writes latents.safetensors and records `info` (file name set here) in scene.json.
// info.windows[i] must match latents[i]: T' = 1 + (count-1)/4, h = height/8, w = width/8.
// Equivalent to stage_scene_latents then commit_scene_latents.
void write_scene_latents(Scene& scene, LatentInfo info, const std::vector<WindowLatents>& latents);

// Two steps for tools that write many scenes and must change none when one
// fails (flat_latents): staging writes the file under a name no reader looks
// at ("latents.safetensors.staged-<pid>"), leaving the scene as it was;
// commit renames it into place and rewrites scene.json; discard removes it.
struct StagedLatents {
  std::string path;  // the staged file
  LatentInfo info;   // what commit records
};
StagedLatents stage_scene_latents(const Scene& scene, LatentInfo info, const std::vector<WindowLatents>& latents);
void commit_scene_latents(Scene& scene, const StagedLatents& staged);
void discard_staged_latents(const StagedLatents& staged);  // never throws
// Removes staged files that a killed run left in the scene folder; returns how many.
int remove_stale_staged_latents(const Scene& scene);

// Reads window i; checks shapes against scene.json and names scene and file on errors.
// camera_rays: "rppc" (the paper) puts "camera.<i>" in .camera, "plucker" puts
// "camera_plucker.<i>" there (an error naming the scene when it has none).
WindowLatents read_window_latents(const Scene& scene, size_t window, const std::string& camera_rays = "rppc");

}  // namespace flat::data
