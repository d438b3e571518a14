// Learning rate at a step: linear warm-up from 0 to the peak over
// warmup_steps, then constant, cosine or linear decay to min_lr_ratio * peak
// at the last step.
#pragma once
#include <cstdint>
#include <string>

namespace flat::train {

struct LrSchedule {
  double peak = 1e-4;
  int64_t warmup_steps = 0;
  int64_t total_steps = 1;
  std::string shape = "cosine";  // constant | cosine | linear
  double min_ratio = 0.1;
  // step counts from 0 (the first update).
  double at(int64_t step) const;
};

}  // namespace flat::train
