// Shared steps of the importers (internal): output size, frame writing, the
// camera sanity log line.
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <utility>

#include <ATen/ATen.h>

#include "flat/core/staged_dir.h"
#include "flat/data/geometry_maps.h"
#include "flat/data/importers.h"
#include "flat/data/scene.h"

namespace flat::data::detail {

// Image size after limiting the longest side to max_size (0 = unchanged).
std::pair<int64_t, int64_t> import_size(int64_t height, int64_t width, int64_t max_size);

// Resizes rgb (3,H,W) to the scene size and writes images/<stem>.png; returns the relative path.
std::string write_import_image(const Scene& scene, int64_t index, const at::Tensor& rgb);

// The scene's name when none is given: the output folder's name, also for
// "out/scene/" (whose filename() is empty).
std::string default_scene_name(const std::string& out_dir);

// Re-orthonormalises the rotation of a c2w (4,4) (float noise in source files).
// A rotation block that is no rotation at all (all zero, rank-deficient: its
// smallest singular value under 1e-3 of its largest) or a reflection is
// refused with `where` (the file and frame), never replaced by a guess.
at::Tensor rigid(const at::Tensor& c2w, const std::string& where);

// The scene is built in "<out_dir>.incomplete-<pid>" and moved into place by
// finish_import, so a failed import leaves an earlier scene at out_dir as it
// was. An existing out_dir is refused unless `overwrite` (an empty folder
// counts as absent). Call it after the inputs are parsed, before frames are written.
std::unique_ptr<StagedDir> begin_import(const std::string& out_dir, bool overwrite);

// Frame `index` appended to the scene: its image written (rgb (3,H,W) as
// read), its depth and normal maps attached (geometry_maps.h: the source
// image was source_height x source_width, `distortion` removed at the output
// size). frame.intrinsics must be set.
void add_import_frame(Scene& scene, int64_t index, SceneFrame frame, const at::Tensor& rgb, GeometryImport& geometry,
                      int64_t source_height, int64_t source_width, const Distortion& distortion = {});

// Records the scene's maps (GeometryImport::finish), writes scene.json into
// the staging folder, moves the folder to its target (scene.dir becomes the
// target) and logs the principal-axes focus of the cameras.
void finish_import(Scene& scene, const GeometryImport& geometry, StagedDir& staged);

}  // namespace flat::data::detail
