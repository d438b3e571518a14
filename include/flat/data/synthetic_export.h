// Synthetic rooms exported in the formats real users bring (issue #43), so
// that import -> latents -> training can be rehearsed with known answers
// (docs/data_tools.md, "flat_synth --format"). The rooms are flat_synth's:
// clip i is the scene flat_synth renders with seed*1000003+i.
//
//   re10k  ROOT/cameras/<clip>.txt           RealEstate10K camera file: a URL line, then per frame
//                                           "timestamp fx fy cx cy 0 0 r00 r01 r02 t0 r10 r11 r12 t1 r20 r21 r22 t2"
//                                           (intrinsics / width, height; 3x4 world-to-camera, OpenCV axes)
//          ROOT/frames/<clip>/<timestamp>.png   8-bit RGB
//          ROOT/depth/<clip>/<timestamp>.npy    float32 (H,W) z-depth in units (metres / unit), 0 = unknown
//          ROOT/normals/<clip>/<timestamp>.png  8-bit RGB, 0.5 n + 0.5 of the OpenGL camera-space normal
//                                               (x right, y up, z backward); (0,0,0) bytes = unknown
//   dl3dv  ROOT/<scene>/transforms.json     nerfstudio: fl_x fl_y cx cy w h (pixels of the full-resolution
//                                           capture, 4x the stored images, as DL3DV's), camera_model OPENCV
//                                           with zero distortion, frames[].file_path "images_4/frame_00001.png",
//                                           frames[].transform_matrix camera-to-world 4x4, OpenGL axes
//          ROOT/<scene>/images_4/frame_00001.png   8-bit RGB
//          ROOT/<scene>/depth/frame_00001.png      16-bit, round(depth_m * 1000 / unit), 0 = unknown
//          ROOT/<scene>/normals/frame_00001.npy    float32 (H,W,3) OpenGL camera-space unit normals, 0 = unknown
//   both   ROOT/manifest.json                what was written: seed, unit, clips, corrupt clips and how
//          ROOT/truth/<clip>/ (re10k), ROOT/<scene>/truth/ (dl3dv)
//                                           the metric ground truth as a flat scene folder (scene.json with
//                                           OpenCV c2w in metres, images, EXR depth and normals)
// Translations and depth are written in units of `unit` metres (real poses
// are scale-ambiguous): importing with --scale unit restores metres.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "flat/data/synthetic_scene.h"

namespace flat::data {

struct SynthExportOptions {
  std::string format = "re10k";  // re10k | dl3dv
  int64_t count = 1;             // clips (re10k) or scenes (dl3dv)
  uint64_t seed = 0;             // base seed: clip i renders flat_synth's scene i (seed*1000003+i)
  double unit = 0.5;             // metres per written unit of translation and depth
  int64_t corrupt = 0;           // clips made corrupt on purpose (chosen by seed), listed in the manifest
  bool truth = true;             // write the truth folders (metric scene folders)
  bool overwrite = false;        // replace an existing ROOT (only once the new one is complete)
  SynthOptions synth;            // family, motion, frames, size, frame_threads, on_frame (its seed is ignored)
  void check() const;            // throws flat::Error naming the bad option
};

struct ExportedClip {
  std::string name;        // re10k: 16 hex digits; dl3dv: 64 hex digits (as the real datasets name them)
  int64_t index = 0;       // flat_synth's scene index
  uint64_t synth_seed = 0;  // seed*1000003+index
  std::string motion;      // resolved motion of the camera path
  std::string corrupt;     // "" or the kind: truncated_line, missing_frame, truncated_json, non_orthonormal
};

// The scene seed flat_synth uses for scene `index` of a batch with base `seed`.
uint64_t synth_scene_seed(uint64_t seed, int64_t index);

// Renders o.count rooms and writes them to `root` in o.format, with
// manifest.json (and the truth folders when o.truth). ROOT is built beside itself and
// renamed into place: it appears whole or not at all; an existing ROOT is
// refused before anything is rendered unless o.overwrite.
std::vector<ExportedClip> export_synthetic(const SynthExportOptions& o, const std::string& root);

}  // namespace flat::data
