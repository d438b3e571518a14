// Precomputed latents of a scene (paper, Model Training: "For each video, we
// precompute its latents using the frozen VAE"). A scene holds one file per
// latent set (a frame size and window length, scene.h), named
// <scene>/latents_<H>x<W>_f<F>.safetensors (version-1 scenes: latents.safetensors):
//   "video.<i>"  (16,T',h,w) normalised VAE latent of window i
//   "camera.<i>" (32,T',h,w) RPPC camera latents of window i (E_ref ; E_dir)
//   "camera_plucker.<i>" (32,T',h,w) optional: Plucker camera latents (the
//                conditioning ablation; flat_latents --camera-rays rppc,plucker)
//   "frames.<i>" (F,) int64 the frames window i covers, F = 1+4(T'-1)
// Metadata: format "flat-scene-latents", version, encoder "pretrained"|"random",
// weights (file name), seed, height, width. scene.json repeats this under
// "latent_sets" (LatentInfo) so a loader can choose windows without opening the file.
#pragma once
#include <vector>

#include <ATen/ATen.h>

#include "flat/data/scene.h"

namespace flat::data {

// "latents_176x320_f17.safetensors": the file of one set.
std::string latent_set_file(int64_t height, int64_t width, int64_t frames);

struct WindowLatents {
  at::Tensor video;   // (16,T',h,w)
  at::Tensor camera;  // (32,T',h,w)
  at::Tensor camera_plucker;  // (32,T',h,w) or undefined (written only when asked for)
};

// Writes the set's file and records `info` (file name set here) among the
// scene's sets in scene.json, replacing a set of the same size and window and
// leaving every other set's file and entry as they were; makes it scene.latents.
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
