// One scene's scores gathered a chunk of views at a time (evaluate_scene,
// scene_evaluation.h): PSNR, SSIM, LPIPS and the baselines per view, averaged
// over the views at the end; normal accuracy and planar roughness summed over
// the pixels they are measured on, so that the average weighs every pixel
// alike whatever chunk it came in.
#pragma once
#include <cstdint>
#include <vector>

#include <ATen/ATen.h>

#include "flat/data/scene_frames.h"
#include "flat/eval/scene_evaluation.h"

namespace flat::eval {

// One chunk of evaluation views: the scene's frame indices, the renders (on
// the pipeline's device) and the ground truth fitted to the evaluation size.
struct ViewChunk {
  std::vector<int64_t> frames;
  pipeline::RenderedViews rendered;
  data::FrameBatch truth;
};

class SceneScoreSums {
 public:
  // The swap baseline's frames are fitted to H x W like the scene's; LPIPS
  // runs on `device` (an empty `lpips`: none).
  SceneScoreSums(const EvalSettings& settings, loss::Lpips lpips, const BaselineInputs& baselines, int64_t H,
                 int64_t W, const at::Device& device);

  void add(const ViewChunk& chunk);

  // The averages into `score` (NaN where nothing was measured), with the
  // pixel counts they are over.
  void write(SceneScore& score) const;

 private:
  void add_image_scores(const ViewChunk& c, const at::Tensor& rgb, const at::Tensor& target);
  void add_swap(const ViewChunk& c, const at::Tensor& rgb);
  void add_geometry(const ViewChunk& c);

  const EvalSettings& settings_;
  loss::Lpips lpips_;
  BaselineInputs baselines_;
  int64_t H_, W_;
  at::Device device_;
  std::vector<double> psnr_, ssim_, lpips_values_, mean_colour_, dataset_mean_, swap_, si_log_;
  double l1_sum_ = 0, cos_sum_ = 0, roughness_sum_ = 0;
  int64_t normal_pixels_ = 0, planar_pixels_ = 0;
};

}  // namespace flat::eval
