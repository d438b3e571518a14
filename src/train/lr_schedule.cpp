#include "flat/train/lr_schedule.h"

#include <algorithm>
#include <cmath>

#include "flat/core/error.h"

namespace flat::train {

double LrSchedule::at(int64_t step) const {
  FLAT_CHECK(step >= 0, "lr schedule: negative step");
  if (step < warmup_steps) return peak * double(step + 1) / double(warmup_steps);
  const int64_t decay_steps = total_steps - warmup_steps;
  if (shape == "constant" || decay_steps <= 1) return peak;
  // progress 0 at the first step after warm-up, 1 at the last step.
  const double progress = std::min(1.0, double(step - warmup_steps) / double(decay_steps - 1));
  const double low = peak * min_ratio;
  if (shape == "linear") return peak + (low - peak) * progress;
  if (shape == "cosine") return low + (peak - low) * 0.5 * (1 + std::cos(M_PI * progress));
  fail("lr schedule: unknown shape '" + shape + "' (constant, cosine, linear)");
}

}  // namespace flat::train
