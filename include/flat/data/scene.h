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

inline constexpr int kSceneFormatVersion = 1;
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

// What latents.safetensors holds and how it was made.
struct LatentInfo {
  std::string file;              // "" = the scene has no latents
  std::string encoder;           // "pretrained" | "random"
  std::string weights;           // file name of the encoder weights ("" when random)
  int64_t seed = 0;              // initialisation seed when random
  int64_t height = 0, width = 0; // frame size the latents were encoded at
  std::string dtype = "float32";
  bool plucker = false;          // "camera_plucker.<i>" are present too (the conditioning ablation)
  std::vector<LatentWindow> windows;
  bool present() const { return !file.empty(); }
};

struct Scene {
  std::string dir;   // folder holding scene.json (absolute or as given)
  std::string name;  // defaults to the folder name
  std::string source;
  double metric_scale = 1.0;  // factor already applied to translations and depth
  int64_t width = 0, height = 0;
  std::vector<SceneFrame> frames;
  bool has_depth = false;    // every frame has depth (all or none)
  bool has_normals = false;  // every frame has normals (all or none)
  std::string packed;        // "" or "frames.safetensors" (see pack.h)
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

// Writes scene.json atomically (the camera fields through camera_entry()).
void write_scene_json(const Scene& scene);

// Scene folders under `root`: root itself when it holds scene.json, else its
// sub-folders that do, sorted. Throws naming root when there are none.
std::vector<std::string> scene_dirs_under(const std::string& root);

// Zero-padded frame file stem: 7 -> "000007".
std::string frame_stem(int64_t index);

}  // namespace flat::data
