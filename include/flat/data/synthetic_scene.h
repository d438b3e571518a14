// Synthetic scenes with exact RGB, metric z-depth and camera-space normals,
// rendered by ray casting analytic shapes (boxes, spheres) — independent of
// the triangle rasterizer, so they can check it. Deterministic by seed.
//   family "room":   the inside of a box room (walls, floor, ceiling) with
//                    furniture-like boxes along the walls and a few spheres;
//   family "object": a cluster of boxes and spheres on a floor in a large room.
// Camera motions like the paper's training videos: "pan" (rotate in place),
// "zoom" (dolly along the view direction), "orbit" (arc around a target),
// "mixed" (one of the three, chosen by the seed).
#pragma once
#include <functional>
#include <cstdint>
#include <string>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"
#include "flat/data/scene.h"

namespace flat::data {

struct SynthOptions {
  std::string family = "room";   // room | object
  std::string motion = "mixed";  // pan | zoom | orbit | mixed
  int64_t frames = 9;
  int64_t height = 24;
  int64_t width = 32;
  uint64_t seed = 0;
  // Frames rendered at once on plain threads, each frame on one; 0: one per
  // core. Give the process one intra-op thread then (at::set_num_threads(1),
  // as flat_synth does): OpenMP teams of two processes side by side spin
  // against each other, plain threads wait in the kernel (issue #30).
  int64_t frame_threads = 1;
  // Where the rays are cast: the CPU, or a GPU (batches of frames one after
  // another; the outputs come back to the CPU). Float32 either way.
  c10::Device device = c10::Device(c10::kCPU);
  // Frames cast in one batch of rays; 0: one on the CPU, up to 4 M rays on a GPU.
  int64_t frames_per_batch = 0;
  std::function<void()> on_frame;  // after each rendered frame (progress); calls are serialised
  void check() const;  // throws flat::Error naming the bad option
};

struct SynthScene {
  camera::Cameras cameras;  // (F) float32, OpenCV c2w, normalised intrinsics
  at::Tensor images;        // (F,3,H,W) float32 in [0,1]
  at::Tensor depth;         // (F,1,H,W) float32 z-depth in metres (0 = no hit)
  at::Tensor normals;       // (F,3,H,W) float32 camera-space, unit, facing the camera
  at::Tensor surface;       // (F,H,W) int64 id of the surface hit (-1 = none)
  at::Tensor planar;        // (S,) bool: surface id -> planar (box faces) or curved (spheres)
  std::string motion;       // the motion actually used ("mixed" resolved)
};

SynthScene render_synthetic_scene(const SynthOptions& options);

// Writes the scene folder <dir> (scene.json, images/*.png, depth/*.exr,
// normals/*.exr; safetensors instead of PNG/EXR when built without OpenImageIO).
Scene write_synthetic_scene(const SynthScene& scene, const std::string& dir, const std::string& name,
                            const std::string& source);

}  // namespace flat::data
