// GPU activities (kernels, copies, memsets) of a piece of work, recorded with
// libtorch's Kineto profiler, and the tables flat_bench prints from them:
// where the GPU time goes without Nsight Systems (not on the GPU machine).
#pragma once
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

namespace flat::bench {

// One GPU activity. Times are on the profiler's clock, the one
// gpu_profile_clock_ns() reads on the host.
struct GpuActivity {
  int64_t start_ns = 0, end_ns = 0;
  std::string name;
  double ms() const { return double(end_ns - start_ns) * 1e-6; }
};

// Runs work (on the current CUDA device) under the profiler, recording GPU
// activities only (recording host ops would slow the host and open idle gaps
// an unprofiled run does not have). Synchronises before and after; the
// result is sorted by start time.
std::vector<GpuActivity> record_gpu_activities(const std::function<void()>& work);

// The host time on the clock of GpuActivity (nanoseconds).
int64_t gpu_profile_clock_ns();

// The function name without namespaces, template arguments or parameters.
std::string short_kernel_name(const std::string& name);

// A coarse class of a kernel by its name: convolution forward / backward data
// / backward weight (cuDNN and CUTLASS), GEMM, layout transforms, elementwise,
// reductions, copies, memsets, the rasterizer's, other.
std::string kernel_class(const std::string& name);

// "ms  share  key xN" rows of the `top` largest groups of activities by
// key(name), under a title line with their total.
void print_grouped(const std::string& title, const std::vector<GpuActivity>& activities, size_t top,
                   const std::function<std::string(const std::string&)>& key);

}  // namespace flat::bench
