// Renders a decoded scene along a camera trajectory, a few views at a time
// (memory bounded by the chunk, not the trajectory's length), and writes each
// view: with OpenImageIO, <folder>/{rgb,depth,normal,alpha}/<view>.png; without
// it, <folder>/<view>.safetensors holding the same four tensors (float32).
// PNG depth is for looking at: grey, near bright, over the scene's depth
// range [depth_lo, depth_hi]; normals are 0.5 n + 0.5 (camera space, OpenCV).
#pragma once
#include <cstdint>
#include <string>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"
#include "flat/pipeline/scene_pipeline.h"
#include "flat/primitives/scene_primitives.h"

namespace flat::infer {

struct TrajectoryRenders {
  int64_t views = 0;
  double seconds = 0;
  double mean_alpha = 0;       // coverage over all views
  double uncovered = 0;        // share of pixels with alpha < 0.5 (the scene does not reach there)
  std::pair<double, double> depth_range{0, 0};  // metres shown as depth, near (bright) to far
  at::Tensor video_frames;     // (V,3,H,3W) uint8: rgb | depth | normals side by side (when asked)
};

// Depth range for display: the 2nd and 98th percentile of the triangle
// centroids' depth (those in front) in each of `cameras`, the lowest and the
// highest of them; falls back to [0.1, 10].
std::pair<double, double> display_depth_range(const primitives::ScenePrimitives& scene, const camera::Cameras& cameras);

// scene: one scene, already pruned (the pipeline prunes again with its own
// threshold). folder: where the files go ("" = write nothing).
TrajectoryRenders render_trajectory(pipeline::ScenePipeline& pipeline, const primitives::ScenePrimitives& scene,
                                    const camera::Cameras& cams, int64_t height, int64_t width,
                                    const std::string& folder, int64_t chunk, bool keep_video_frames,
                                    std::pair<double, double> depth_range, const std::string& progress_label);

}  // namespace flat::infer
