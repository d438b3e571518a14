// Validation on held-out scenes (paper, Evaluation): decode each held-out
// sample's latents, render its target views, and score them against the
// ground truth with the metrics of the paper's Table 1: PSNR, SSIM, LPIPS and
// normal cosine (normals only where alpha > 0.5). Beside them, the scores a
// model that ignores its input would also reach (a result only counts where
// it clears them):
//   mean-colour oracle: every view painted its own mean colour;
//   dataset mean: every view predicted as the training set's mean image (the
//     best "same output for every scene");
//   swap: each sample's renders scored against the ground truth of the next
//     sample (cyclically) that shows another scene, same view index; a model
//     that ignores its latents scores the same on its own scene and on the
//     swapped one.
// Writes an image grid for a person to look at.
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
  double dataset_mean_psnr = NAN;  // the training set's mean image on the same views
  double swap_psnr = NAN;          // renders against the next other-scene sample's ground truth
  double latent_correlation = NAN; // VAE stage: mean Pearson correlation of the samples' latents
  int64_t samples = 0, views = 0;
  at::Tensor grid;             // (3,H',W') in [0,1]: one row per sample (its first view)
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
// The grid holds the first view of each of the first `grid_views` samples
// (one row each), so that different held-out scenes can be told apart.
// dataset_mean: (3,H,W) in [0,1], the training set's mean image at the
// validation size (training_mean_image), or undefined (no such baseline).
// bf16: decode and render under CUDA bf16 autocast, as the run trains and as
// flat_eval scores by default; the scores are computed in fp32.
ValidationResult validate(pipeline::ScenePipeline& pipeline, data::Loader& loader, int64_t samples,
                          loss::Lpips lpips, int64_t grid_views, distributed::ProcessGroup* group = nullptr,
                          const at::Tensor& dataset_mean = {}, bool bf16 = false);

// The mean target image of `samples` training samples (batches 0.. of a
// loader built from `config` with batch size 1): (3,H,W) on the CPU.
at::Tensor training_mean_image(const data::LoaderConfig& config, int64_t samples);

}  // namespace flat::train
