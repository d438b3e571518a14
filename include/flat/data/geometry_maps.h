// Depth and normals from external predictors (the paper: metric depth from
// MapAnything, normals from NormalCrafter, run beforehand), attached to the
// frames of an import (docs/data_tools.md, "Depth and normals from predictors").
//
// Files: the map of a frame whose source image is <stem>.<ext> is
// <dir>/<stem>.exr|.npy|.png (auto: the first that exists, in that order).
// Either every imported frame has a map or the import fails naming the first
// frame without one.
//   depth    metric z-depth along the optical axis (not along the ray), 0 = unknown:
//            EXR (1 channel, or grey RGB), NPY (H,W) (1,H,W) (H,W,1) float16/32/64,
//            16-bit greyscale PNG times depth_png_scale metres per unit (8-bit refused).
//   normals  camera-space unit vectors facing the camera, 0 = unknown:
//            EXR (3 channels), NPY (H,W,3) (3,H,W) float16/32/64, PNG (8 or 16 bit)
//            encoding 0.5 n + 0.5 (an all-zero pixel = unknown); OpenCV axes
//            (x right, y down, z forward) or OpenGL (x right, y up, z backward:
//            y and z are negated on import).
// Checks (errors name the map file): the map's size equals its source image's;
// values finite; depth >= 0; nonzero normals of unit length within 0.05 (0.1
// for PNG); at most half of the known normals facing away from the camera
// (n . ray > 0 with ray = ((u+0.5-cx)/fx, (v+0.5-cy)/fy, 1)), else the
// convention is wrong. The few away-facing normals that remain are kept and
// counted in the log. Depth is multiplied by the import's metric scale, like
// the translations. Maps follow the image: resized with nearest neighbour (no
// depth blended across an edge; normals renormalised) and undistorted with the
// image's remap, sampled nearest (depth and camera-space normals of a surface
// point do not change when only its pixel moves); pixels whose source lies
// outside become 0 (unknown).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <ATen/ATen.h>

#include "flat/data/scene.h"
#include "flat/data/undistort.h"

namespace CLI {
class App;
}

namespace flat::data {

struct GeometryOptions {
  std::string depth_dir, normals_dir;            // "" = no depth / no normals
  std::string depth_format = "auto";             // auto|exr|npy|png16
  double depth_png_scale = 0;                    // metres per unit of a 16-bit PNG; required for png16
  // The maps are already metric (MapAnything's depth) while the poses need
  // --scale: the metric scale then applies to the poses only.
  bool depth_metric = false;
  std::string normals_format = "auto";           // auto|exr|npy|png
  std::string normals_convention = "opencv";     // opencv|opengl
  bool any() const { return !depth_dir.empty() || !normals_dir.empty(); }
};

// --depth DIR --depth-format --depth-png-scale --normals DIR --normals-format
// --normals-convention (the format and convention options need their folder).
// A --depth / --normals folder must exist (a usage error naming the flag and
// the path); a batch pattern with {clip} (import_batch.h) is checked per clip
// as it is imported, and the folder above its first {clip} at once.
void add_geometry_options(CLI::App& app, GeometryOptions& options);

// The map file of the frame whose source image is `image` in `dir` for
// `format` (auto|exr|npy|png16|png), or "" when there is none.
std::string find_geometry_map(const std::string& dir, const std::string& image, const std::string& format);

// Reads a depth map and checks it against its frame's source image (`image`,
// height x width): (1,H,W) float32, in the file's units times depth_png_scale
// for PNG (the metric scale is not applied here).
at::Tensor read_predicted_depth(const std::string& path, const GeometryOptions& options, int64_t height,
                                int64_t width, const std::string& image);
// Reads a normal map, checks it and returns (3,H,W) float32 in OpenCV axes,
// renormalised, 0 where unknown.
at::Tensor read_predicted_normals(const std::string& path, const GeometryOptions& options, int64_t height,
                                  int64_t width, const std::string& image);

// Known (nonzero) normals of a (3,H,W) OpenCV map and how many face away from
// the camera of normalised intrinsics (4,) [fx/W, fy/H, cx/W, cy/H].
struct FacingCount {
  int64_t known = 0, away = 0;
};
FacingCount count_away_facing(const at::Tensor& normals, const at::Tensor& intrinsics);

// The importers' hook: finds every frame's maps up front (`images` are the
// source images of the imported frames, in order), then per frame reads,
// checks, converts, resizes / undistorts and writes them into the scene.
class GeometryImport {
 public:
  GeometryImport(const GeometryOptions& options, double metric_scale, const std::vector<std::string>& images);
  bool active() const { return options_.any(); }
  // Frame `index` of `scene` (scene.height x scene.width, frame.intrinsics
  // set), whose source image was source_height x source_width before the
  // importer resized it and removed `distortion` at the output size. Writes
  // depth/<stem> and normals/<stem> and sets frame.depth / frame.normals.
  void attach(Scene& scene, int64_t index, SceneFrame& frame, int64_t source_height, int64_t source_width,
              const Distortion& distortion = {});
  // Sets has_depth / has_normals and depth_source / normals_source; logs the
  // away-facing normals that were kept.
  void finish(Scene& scene) const;

 private:
  GeometryOptions options_;
  double metric_scale_ = 1;
  std::vector<std::string> images_, depth_files_, normals_files_;
  std::string depth_dir_abs_, normals_dir_abs_;
  std::vector<std::string> depth_formats_, normals_formats_;  // the file kinds seen, for the source line
  int64_t known_ = 0, away_ = 0, frames_with_away_ = 0;
};

}  // namespace flat::data
