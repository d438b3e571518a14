#include "flat/bench/timing.h"

#include <algorithm>
#include <chrono>

#include <torch/cuda.h>

namespace flat::bench {

double now_ms() {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

void sync_device(const at::Device& d) {
  if (d.is_cuda()) torch::cuda::synchronize();
}

}  // namespace flat::bench
