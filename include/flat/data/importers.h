// Importers from public capture formats into scene folders (docs/data_tools.md).
//   transforms.json (NeRF / instant-ngp / nerfstudio, the layout of DL3DV):
//     c2w in OpenGL axes (x right, y up, z backward) -> OpenCV by negating the
//     y and z columns; fl_x, fl_y, cx, cy in pixels (or camera_angle_x);
//     OpenCV radial-tangential distortion k1, k2, [k3], p1, p2 is removed from
//     the images; per-frame values override the global ones (nerfstudio).
//   RealEstate10K camera files: a URL line, then one line per frame
//     "timestamp fx fy cx cy 0 0 r00 r01 r02 t0 r10 ... t2" with normalised
//     intrinsics and a row-major 3x4 world-to-camera matrix (OpenCV axes).
// Both apply a metric scale factor to the translations (the paper rescales
// poses with a metric depth model; here the factor is an input).
#pragma once
#include <cstdint>
#include <string>

#include "flat/data/geometry_maps.h"
#include "flat/data/scene.h"

namespace flat::data {

struct ImportOptions {
  std::string name;           // scene name ("" = output folder name)
  double metric_scale = 1.0;  // multiplies camera translations (and depth, if any)
  int64_t max_size = 0;       // longest image side after import (0 = keep)
  int64_t stride = 1;         // keep every stride-th frame
  int64_t max_frames = 0;     // 0 = all
  bool skip_missing = false;  // transforms.json: skip frames whose image is missing (else an error)
  bool overwrite = false;     // replace an existing scene folder (only once the new one is complete)
  GeometryOptions geometry;   // depth / normal maps from predictors to attach (geometry_maps.h)
};

// Both build the scene in a staging folder beside out_dir and rename it into
// place when complete: a failed import leaves out_dir as it was. An existing
// out_dir (not empty) is refused unless options.overwrite.
// `source` is a transforms.json file or a folder holding one.
Scene import_transforms_json(const std::string& source, const std::string& out_dir, const ImportOptions& options);

// `camera_file` is the RE10K .txt; frames are `frames_dir/<timestamp>.{png,jpg}`
// or, failing that, the images of frames_dir in name order (one per line).
Scene import_re10k(const std::string& camera_file, const std::string& frames_dir, const std::string& out_dir,
                   const ImportOptions& options);

}  // namespace flat::data
