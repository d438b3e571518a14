// The opacity scale at the start of a stage that prunes (paper, stage 4:
// "remove triangles with opacity below 40%").
//
// A stage trained without pruning leaves a soft soup: each surface is painted
// by many nearly transparent triangles, one from each frame that sees it (the
// recipe's stage 3: mean opacity 0.055). Pruned at 0.4 almost nothing is
// left, and pruned triangles get no gradient, so the next stage spends its
// steps regrowing (docs/training.md "Stage 4 from one shared stage 3").
// The decoder's opacity is sigmoid(x - pipeline.triangles.opacity_shift): a
// lower shift makes every triangle more opaque together, keeping their order
// and their relative opacities. calibrate_opacity_shift tries shifts on a few
// training batches, rendered and pruned as the stage will train, and keeps
// the one whose renders fit the targets best (training config key
// opacity_shift_calibration; the trainer writes the chosen shift into the
// run's config and the model file).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <ATen/ATen.h>

#include "flat/data/loader.h"
#include "flat/loss/objective.h"
#include "flat/pipeline/scene_pipeline.h"

namespace flat::train {

class DataParallel;

struct OpacityShiftTrial {
  double shift = 0;  // pipeline.triangles.opacity_shift tried
  double rgb = 0;    // the objective's rgb term over the batches (mean over ranks)
  double kept = 0;   // the share of primitives at or above the pruning threshold
};

struct OpacityShiftCalibration {
  std::vector<OpacityShiftTrial> trials;  // in the order tried: the current shift first
  double best = 0;                        // the shift of the lowest rgb term
  std::string table() const;              // one line a trial, for the log
};

// The shifts tried: the current one, then lower by 0.5 down to 6 below it
// (a higher shift only makes more triangles fall under the threshold; the
// recipe's stage-3 soup, mean opacity 0.055, has many triangles at opacity
// 0.01, logit -4.6, that need more than 4 to pass 0.4).
std::vector<double> opacity_shift_candidates(double current);

// Opacities decoded under shift `from`, as the decoder gives them under `to`:
// sigmoid(logit(o) + from - to). Exact up to float rounding (o is clamped
// inside (0, 1) first).
at::Tensor reshift_opacities(const at::Tensor& opacities, double from, double to);

// Decodes batches 0 .. batches-1 of `loader` (Loader::batch: its next() is left as it is) once (no gradient) and scores every
// candidate shift on them: renders pruned at `prune_opacity`, composited over
// the stage's backgrounds (background_seed >= 0: random ones, as its training
// steps; -1: the configured one), and the objective's rgb term. With data
// parallelism (`dp`, every rank calls it on its own batches) the terms are
// averaged over the ranks, so that every rank chooses the same shift.
OpacityShiftCalibration calibrate_opacity_shift(pipeline::ScenePipeline& pipeline, loss::Objective& objective,
                                                data::Loader& loader, int64_t batches, double prune_opacity,
                                                bool bf16, int64_t background_seed, DataParallel* dp);

}  // namespace flat::train
