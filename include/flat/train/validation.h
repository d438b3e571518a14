// Validation on held-out scenes (paper, Evaluation), scored exactly as
// flat_eval scores them (eval/scene_evaluation.h), so that the trainer's
// validation and flat_eval give one number for one model: each held-out scene
// decoded from window 0 of the stage's latent set, every view of the scene
// (or max_views of them, evenly spaced) rendered at the set's size, PSNR,
// SSIM, LPIPS per view averaged per scene, normal L1 and cosine where alpha >
// 0.5; the figure is the mean over the scenes, as flat_eval's table. Beside
// them, the scores a model that ignores its input would also reach (a result
// only counts where it clears them), the same as flat_eval's:
//   mean-colour oracle: every view painted its own mean colour;
//   dataset mean: every view predicted as the other held-out scenes' mean
//     frame of the same index (the best "same output for every scene");
//   swap: each scene's renders scored against the next held-out scene's
//     frames (cyclically); a model that ignores its latents scores the same
//     on its own scene and on the swapped one.
// Writes an image grid for a person to look at.
#pragma once
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <ATen/ATen.h>

#include "flat/data/loader.h"
#include "flat/eval/baselines.h"
#include "flat/eval/scene_evaluation.h"
#include "flat/distributed/process_group.h"
#include "flat/loss/lpips.h"
#include "flat/pipeline/scene_pipeline.h"
#include "flat/train/metrics_log.h"

namespace flat::train {

struct ValidationResult {
  double psnr = 0, ssim = 0;
  double lpips = NAN;          // NaN without LPIPS weights
  double normal_cosine = NAN;  // NaN where no scene has reference normals
  double normal_l1 = NAN;
  double depth_si_log = NAN;      // eval/depth_metrics.h; NaN where no scene has reference depth
  double planar_roughness = NAN;  // texture leaking into depth (eval/depth_metrics.h)
  double mean_colour_psnr = 0; // the mean-colour baseline on the same views
  double dataset_mean_psnr = NAN;  // the other held-out scenes' mean frame on the same views
  double swap_psnr = NAN;          // renders against the next held-out scene's frames
  double latent_correlation = NAN; // VAE stage: mean Pearson correlation of the samples' latents
  int64_t samples = 0, views = 0;  // held-out scenes (VAE stage: windows) and views scored
  at::Tensor grid;             // (3,H',W') in [0,1]: one row per scene (its first view)
  Scalars scalars() const;     // "val_psnr", "val_ssim", ...
};

// Rows: views of the first samples; columns: ground truth, render, rendered
// depth, reference depth, rendered normals, reference normals (depth as grey
// levels scaled by the reference's range, normals as 0.5 n + 0.5).
at::Tensor validation_grid(const pipeline::RenderedViews& views, const data::Batch& batch, int64_t b,
                           int64_t max_views);

// The held-out scenes and the dataset each comes from: the baselines, as
// flat_eval's, pair a scene with the next of its own dataset (swap) and with
// the mean frame of its dataset's other scenes.
struct HeldOut {
  std::vector<data::Scene> scenes;
  std::vector<size_t> dataset;                  // index into validation.datasets, per scene
  std::map<size_t, eval::FrameSums> frame_sums;  // per dataset (measure_frames)
  void measure_frames(const eval::EvalSettings& settings);
  std::optional<size_t> swap_partner(size_t scene) const;
};

// Those of `datasets` (weight > 0) in name order, dataset by dataset, at most
// `count` (0 = all), each with the latent set of the stage (its size and
// window length) chosen; scenes without that set are left out (the
// validation loader reports them). Throws when none is left.
HeldOut held_out_scenes(const std::vector<data::DatasetSource>& datasets, int64_t count, int64_t height,
                        int64_t width, int64_t frames);

// flat_eval's default settings (views "scene", window 0, skimage SSIM) with
// at most `max_views` views per scene (0 = all) and the run's precision:
// `flat_eval --max-views N` (with --latent-set of the stage when the scenes
// hold several sets) scores the same views.
eval::EvalSettings validation_settings(int64_t max_views, bool bf16);

// Scores every scene (flat_eval's evaluate_scene). lpips: an empty holder
// skips LPIPS. With `group` (every rank calls it) rank r scores scenes r,
// r + W, ... and the sums are added over the ranks: every rank gets the
// scores of all scenes, rank 0 the grid. The grid holds the first view of
// each of the first `grid_views` scenes (one row each).
ValidationResult validate(pipeline::ScenePipeline& pipeline, const HeldOut& held_out,
                          const eval::EvalSettings& settings, loss::Lpips lpips, int64_t grid_views,
                          distributed::ProcessGroup* group = nullptr);

}  // namespace flat::train
