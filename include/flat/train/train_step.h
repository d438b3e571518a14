// One training step's forward and backward (paper, Model Training and Losses):
//
//   batch latents -> pipeline.decode -> per scene: pipeline.render into the
//   target views -> loss::Objective (L2, LPIPS, disparity, normals, opacity)
//   -> backward into the scene decoder's parameters.
//
// The backward runs in two phases, through the loss and rasterizer to the
// triangles, then through the triangle builder and the decoder, so that a
// timed step (flat_bench train) can say where the time goes without changing
// what is computed. With bf16 on CUDA the forward runs under autocast; the
// weights, the triangles and the rasterizer stay float32.
#pragma once
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include <ATen/ATen.h>

#include "flat/core/autocast_scope.h"

#include "flat/data/loader.h"
#include "flat/loss/objective.h"
#include "flat/pipeline/scene_pipeline.h"

namespace flat::train {

// Seconds per phase of one step (filled only when timing: each phase ends
// with a device synchronisation).
struct StepTimes {
  double decode_forward = 0, render_forward = 0, loss_forward = 0;
  double render_loss_backward = 0, decoder_backward = 0;
  // When each phase ended, on the profiler's clock (c10::getTime), in the
  // order above: flat_bench train --profile places GPU kernels in phases by it.
  std::vector<int64_t> phase_end_ns;
};

struct StepResult {
  bool finite = true;  // false: the triangles or the loss were NaN/Inf and no backward ran
  double loss = 0;
  std::map<std::string, double> terms;  // unweighted, averaged over the batch's scenes
  int64_t triangles = 0;                // rendered (after pruning), summed over scenes
  std::string nonfinite;                // when !finite: what was NaN/Inf (for the log)
};


// Forward and backward of one batch; gradients accumulate into the decoder's
// parameters (the caller zeroes them). times: optional per-phase timing.
// background_seed >= 0: the renders take random backgrounds drawn from it
// (loss.random_background, train/random_background.h); -1: the configured one.
// prune_opacity >= 0: the training renders prune below it instead of the
// pipeline's prune_opacity (prune_warmup_steps, training_prune_opacity).
StepResult forward_backward(pipeline::ScenePipeline& pipeline, loss::Objective& objective, const data::Batch& batch,
                            bool bf16, StepTimes* times = nullptr, int64_t background_seed = -1,
                            double prune_opacity = -1);

// The loss of primitives already decoded from `batch`, without a backward:
// forward_backward's renders (pruned below prune_opacity, < 0: the
// pipeline's; random backgrounds drawn from background_seed >= 0) and
// objective. The opacity calibration (train/opacity_calibration.h) scores
// one decode under several opacity scales with it.
StepResult score_decoded(pipeline::ScenePipeline& pipeline, loss::Objective& objective, const data::Batch& batch,
                         const primitives::ScenePrimitives& scene, int64_t background_seed = -1,
                         double prune_opacity = -1);

// The training renders' pruning threshold at `step`: `target` (the pipeline's
// prune_opacity) times min(1, step / warmup_steps); `target` when warmup_steps is 0.
double training_prune_opacity(double target, int64_t warmup_steps, int64_t step);

}  // namespace flat::train
