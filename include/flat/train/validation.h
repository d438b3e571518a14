// Validation on held-out scenes (paper, Evaluation): decode each held-out
// sample's latents, render its target views, and score them against the
// ground truth with the metrics of the paper's Table 1: PSNR, SSIM, LPIPS and
// normal cosine (normals only where alpha > 0.5). Also the PSNR of painting
// every view its mean colour, the floor a model must clear to show that it
// uses its latents. Writes an image grid for a person to look at.
#pragma once
#include <cstdint>
#include <string>

#include <ATen/ATen.h>

#include "flat/data/loader.h"
#include "flat/distributed/process_group.h"
#include "flat/loss/lpips.h"
#include "flat/pipeline/scene_pipeline.h"
#include "flat/train/metrics_log.h"

namespace flat::train {

struct ValidationResult {
  double psnr = 0, ssim = 0;
  double lpips = NAN;          // NaN without LPIPS weights
  double normal_cosine = NAN;  // NaN where no sample has reference normals
  double mean_colour_psnr = 0; // the mean-colour baseline on the same views
  int64_t samples = 0, views = 0;
  at::Tensor grid;             // (3,H',W') in [0,1]: one row per view (see grid())
  Scalars scalars() const;     // "val_psnr", "val_ssim", ...
};

// Rows: views of the first samples; columns: ground truth, render, rendered
// depth, reference depth, rendered normals, reference normals (depth as grey
// levels scaled by the reference's range, normals as 0.5 n + 0.5).
at::Tensor validation_grid(const pipeline::RenderedViews& views, const data::Batch& batch, int64_t b,
                           int64_t max_views);

// Scores `samples` batches 0.. of `loader` (batch size 1, fixed seed: the same
// views every time). lpips: an empty holder skips LPIPS. With `group` (every
// rank calls it) rank r scores batches r, r + W, ... and the sums are added
// over the ranks: every rank gets the scores of all samples, rank 0 the grid
// (of batch 0).
ValidationResult validate(pipeline::ScenePipeline& pipeline, data::Loader& loader, int64_t samples,
                          loss::Lpips lpips, int64_t grid_views, distributed::ProcessGroup* group = nullptr);

// Writes the grid as PNG (or safetensors when built without OpenImageIO);
// returns the path written.
std::string write_validation_grid(const at::Tensor& grid, const std::string& path_without_extension);

}  // namespace flat::train
