#include "flat/bench/gpu_profile.h"

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <map>
#include <set>

#include <c10/util/ApproximateClock.h>
#include <torch/csrc/autograd/profiler_kineto.h>
#include <torch/torch.h>

namespace flat::bench {

std::vector<GpuActivity> record_gpu_activities(const std::function<void()>& work) {
  namespace prof = torch::autograd::profiler;
  using torch::profiler::impl::ActivityType;
  const torch::profiler::impl::ProfilerConfig cfg(torch::profiler::impl::ProfilerState::KINETO);
  const std::set<ActivityType> acts = {ActivityType::CUDA};
  prof::prepareProfiler(cfg, acts);
  torch::cuda::synchronize();
  prof::enableProfiler(cfg, acts);
  work();
  torch::cuda::synchronize();
  const auto result = prof::disableProfiler();
  std::vector<GpuActivity> out;
  for (const auto& e : result->events()) {
    if (e.deviceType() != c10::DeviceType::CUDA) continue;
    out.push_back({int64_t(e.startNs()), int64_t(e.endNs()), e.name()});
  }
  std::sort(out.begin(), out.end(), [](const GpuActivity& a, const GpuActivity& b) { return a.start_ns < b.start_ns; });
  return out;
}

int64_t gpu_profile_clock_ns() { return int64_t(c10::getTime()); }

std::string short_kernel_name(const std::string& name) {
  std::string n = name;
  for (size_t a; (a = n.find("(anonymous namespace)::")) != std::string::npos;) n.erase(a, 23);
  n = n.substr(0, n.find('('));
  if (n.rfind("void ", 0) == 0) n = n.substr(5);
  const size_t t = n.find('<');
  if (t != std::string::npos) n = n.substr(0, t);
  const size_t c = n.rfind("::");
  return c == std::string::npos ? n : n.substr(c + 2);
}

std::string kernel_class(const std::string& name) {
  std::string n = name;
  std::transform(n.begin(), n.end(), n.begin(), [](unsigned char ch) { return char(std::tolower(ch)); });
  auto has = [&](const char* s) { return n.find(s) != std::string::npos; };
  if (has("memcpy")) return "memcpy";
  if (has("memset")) return "memset";
  if (has("wgrad")) return "conv backward weight (wgrad)";
  if (has("dgrad")) return "conv backward data (dgrad)";
  if (has("fprop") || has("convolve") || has("conv3d") || has("flat::model::cuda::conv")) return "conv forward (fprop)";
  if (has("nchwtonhwc") || has("nhwctonchw") || has("transpose")) return "layout transform";
  if (has("gemm") || has("gemv")) return "gemm";
  if (has("raster") || has("tile_ranges") || has("depth_keys") || has("duplicate_kernel") ||
      has("ordered_counts") || has("row_map"))
    return "rasterizer";
  if (has("rms_norm")) return "fused norm (ours)";
  if (has("reduce") || has("norm_kernel") || has("multi_tensor")) return "reduction / multi-tensor";
  if (has("cat") || has("copy") || has("index") || has("gather") || has("scatter")) return "copy / cat / index";
  if (has("elementwise")) return "elementwise";
  return "other";
}

void print_grouped(const std::string& title, const std::vector<GpuActivity>& activities, size_t top,
                   const std::function<std::string(const std::string&)>& key) {
  std::map<std::string, std::pair<double, int>> groups;  // key -> (ms, activities)
  double total = 0;
  for (const auto& a : activities) {
    auto& g = groups[key(a.name)];
    g.first += a.ms();
    g.second += 1;
    total += a.ms();
  }
  std::vector<std::pair<double, std::string>> rows;
  for (const auto& [k, g] : groups) rows.push_back({g.first, k + " x" + std::to_string(g.second)});
  std::sort(rows.rbegin(), rows.rend());
  std::printf("%s (GPU ms, total %.2f):\n", title.c_str(), total);
  for (size_t i = 0; i < rows.size() && i < top; ++i)
    std::printf("  %9.2f  %5.1f%%  %s\n", rows[i].first, total > 0 ? 100 * rows[i].first / total : 0.0,
                rows[i].second.substr(0, 110).c_str());
}

}  // namespace flat::bench
