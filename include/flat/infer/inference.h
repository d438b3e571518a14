// flat_infer's job (paper: Pipeline Overview; appendix, Pipeline Flexibility):
// a trained decoder turns one window of latents into a triangle scene, which
// is pruned, exported and rendered:
//
//   <out>/scene.ply            triangle soup, our lossless layout (docs/formats.md)
//   <out>/scene.glb            glTF 2.0 with vertex colours and alpha (when built with tinygltf)
//   <out>/cameras/{input,novel}.json
//   <out>/renders/{input,novel}/   RGB, depth, normals, alpha per view (trajectory_renders.h)
//   <out>/videos/{input,novel}.mp4 rgb | depth | normals (when ffmpeg is on the PATH)
//   <out>/viewer/index.html    offline three.js viewer of scene.glb (export/viewer.h)
//   <out>/summary.json, <out>/infer.log
//
// The folder appears whole or not at all (core/staged_dir.h): a failure at
// any point leaves an earlier output as it was. Missing optional tools
// (ffmpeg, three.js, tinygltf) give a note in the log and summary, not an error.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "flat/camera/trajectory.h"
#include "flat/infer/infer_input.h"

namespace flat::infer {

// flat_infer's pruning for a model trained without any (pipeline.prune_opacity 0).
constexpr double kDefaultPruneOpacity = 0.05;

struct InferOptions {
  std::string model;                   // run folder | checkpoint folder | model file
  std::string config;                  // pipeline keys (YAML) layered over the model's own config
  std::vector<std::string> overrides;  // pipeline keys: "raster.window=ts"
  InputSpec input;
  std::string out_dir;
  bool overwrite = false;
  std::string device = "auto";     // auto (cuda when present) | cpu | cuda
  std::string precision = "bf16";  // bf16 (on CUDA; the CPU computes in fp32) | fp32
  bool streaming = true;           // bounded-memory decoding, one latent frame at a time
  // Triangles below this opacity are dropped before export and rendering;
  // < 0: the model's pipeline.prune_opacity (the threshold it was trained
  // with, 0.4 at stage 4), or kDefaultPruneOpacity for a model without one.
  double prune_opacity = -1;
  camera::TrajectorySpec novel;    // preset "none" = no novel renders; a file name = cameras JSON
  int64_t height = 0, width = 0;   // render size (0 = the input frames')
  int64_t render_chunk = 8;        // views per rasterizer call
  bool ply = true, glb = true, renders = true, video = true, viewer = true;
  double fps = 24;
  std::string three_js_dir;        // "" = Debian's libjs-three
  std::string log_level = "info";
};

struct InferSummary {
  std::string out_dir;
  std::string representation = "triangles";  // pipeline.representation of the model
  int64_t triangles_decoded = 0, triangles_kept = 0;  // primitives (triangles or Gaussians)
  double prune_opacity = 0;  // kept: opacity at or above this
  int64_t input_views = 0, novel_views = 0;
  double decode_seconds = 0, export_seconds = 0, render_seconds = 0, total_seconds = 0;
  double decode_peak_gib = 0, render_peak_gib = 0;  // CUDA peak memory (0 on the CPU)
  double input_uncovered = 0, novel_uncovered = 0;  // share of rendered pixels with alpha < 0.5
  // The depth renders' display range (metres, near to far) of each trajectory.
  std::pair<double, double> input_depth_range{0, 0}, novel_depth_range{0, 0};
  std::vector<std::string> outputs;                // what was written, relative to out_dir
  std::vector<std::string> notes;                  // what was skipped and why
};

InferSummary run_inference(const InferOptions& options);

// The one-screen summary printed at the end.
std::string format_summary(const InferSummary& s);

}  // namespace flat::infer
