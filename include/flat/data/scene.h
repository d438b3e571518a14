// A scene folder (docs/scene_format.md): scene.json + frames (RGB), optional
// metric depth and camera-space normals, optional packed frames
// (frames.safetensors) and optional precomputed latents (latents.safetensors).
// Cameras follow the project convention: normalised intrinsics, camera-to-world
// 4x4, OpenCV axes, metres; each frame's camera fields are a camera entry of
// flat/camera/camera_json.h.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"

namespace flat::data {

// Version 2 holds any number of latent sets ("latent_sets"); version 1 (one
// "latents" object) is still read, as one set.
inline constexpr int kSceneFormatVersion = 2;
inline constexpr const char* kSceneFile = "scene.json";

struct SceneFrame {
  at::Tensor intrinsics;  // (4,) float32: fx/W, fy/H, cx/W, cy/H
  at::Tensor c2w;         // (4,4) float32, OpenCV
  std::string image;      // path relative to the scene folder ("" when only packed)
  std::string depth;      // "" = none; metric z-depth along the optical axis, 0 = invalid
  std::string normals;    // "" = none; camera-space unit normals facing the camera, 0 = invalid
  double timestamp = -1;  // source timestamp (RE10K microseconds), -1 = unknown
};

// One latent window: frames [start, start+count) of the video, count = 1+4k.
struct LatentWindow {
  int64_t start = 0;
  int64_t count = 0;
};

// One latent set: the windows of one frame count encoded at one size, in one
// file (latents_<H>x<W>_f<F>.safetensors), and how it was made. A scene holds
// any number of sets, one per (size, window), so the four stages of the paper
// (17 and 49 frames at 176x320, 49 at 360x640 and 432x768) share one folder.
struct LatentInfo {
  std::string file;              // "" = the scene has no latents
  std::string encoder;           // "pretrained" | "random"
  std::string weights;           // file name of the encoder weights ("" when random)
  std::string weights_digest;    // 64-bit FNV-1a of the weights file's bytes, hex ("" = not recorded)
  int64_t seed = 0;              // initialisation seed when random
  int64_t height = 0, width = 0; // frame size the latents were encoded at
  std::string dtype = "float32";
  bool plucker = false;          // "camera_plucker.<i>" are present too (the conditioning ablation)
  std::vector<LatentWindow> windows;
  bool present() const { return !file.empty(); }
  int64_t frames() const { return windows.empty() ? 0 : windows[0].count; }  // every window has this count
};

// "176x320_f17": what identifies a set within a scene.
std::string latent_set_key(int64_t height, int64_t width, int64_t frames);
std::string latent_set_key(const LatentInfo& set);

struct Scene {
  std::string dir;   // folder holding scene.json (absolute or as given)
  std::string name;  // defaults to the folder name
  std::string source;
  double metric_scale = 1.0;  // factor already applied to translations and depth
  int64_t width = 0, height = 0;
  std::vector<SceneFrame> frames;
  bool has_depth = false;    // every frame has depth (all or none)
  bool has_normals = false;  // every frame has normals (all or none)
  std::string depth_source;    // where the depth maps came from ("" = none or not recorded)
  std::string normals_source;  // where the normal maps came from (predictor files, ray-cast, ...)
  std::string packed;        // "" or "frames.safetensors" (see pack.h)
  std::vector<LatentInfo> latent_sets;  // every precomputed latent set, in key order
  // The set that readers of one window use: the only set when there is one,
  // else the one chosen by select_latent_set (empty when several and none chosen).
  LatentInfo latents;

  int64_t size() const { return int64_t(frames.size()); }
  std::string path(const std::string& relative) const { return dir + "/" + relative; }
  std::string json_path() const { return path(kSceneFile); }
  // All cameras (N), or the selected frames.
  camera::Cameras cameras() const;
  camera::Cameras cameras(const std::vector<int64_t>& indices) const;
};

// Reads and validates <dir>/scene.json. With check_files, every referenced file
// must exist. Errors: flat::Error "<dir>/scene.json: frames[3]: ...".
Scene read_scene(const std::string& dir, bool check_files = true);

// Structural checks (sizes, all-or-none depth/normals, windows in range, rigid
// cameras); throws naming the scene file and the key at fault.
void validate_scene(const Scene& scene, bool check_files);

// The set of this size and window frame count, or nullptr.
const LatentInfo* find_latent_set(const Scene& scene, int64_t height, int64_t width, int64_t frames);
// Makes that set scene.latents; throws naming the scene, the set asked for and
// the sets it holds when there is none.
void select_latent_set(Scene& scene, int64_t height, int64_t width, int64_t frames);
// For tools that read one window (flat_infer, flat_eval, flat_mesh): `key`
// ("176x320_f17") picks that set; "" keeps the scene's only set and fails,
// listing the sets, when it holds several. A scene without latents is left as is.
void choose_latent_set(Scene& scene, const std::string& key);
// "176x320_f17" -> height, width, frames; throws naming `what` on another form.
void parse_latent_set_key(const std::string& key, int64_t& height, int64_t& width, int64_t& frames,
                          const std::string& what);
// Adds `set` to scene.latent_sets, replacing the set of the same key; keeps key order.
void put_latent_set(Scene& scene, const LatentInfo& set);
// "176x320_f17, 360x640_f49" (or "none"), for messages.
std::string latent_set_list(const Scene& scene);

// Writes scene.json atomically (the camera fields through camera_entry()).
void write_scene_json(const Scene& scene);

// Scene folders under `root`: root itself when it holds scene.json, else its
// sub-folders that do, sorted. Throws naming root when there are none.
std::vector<std::string> scene_dirs_under(const std::string& root);

// Zero-padded frame file stem: 7 -> "000007".
std::string frame_stem(int64_t index);

}  // namespace flat::data
