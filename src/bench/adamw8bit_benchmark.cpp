// The benchmark behind flat_bench adamw8bit: one 8-bit AdamW step over the scene decoder's
// parameters (73.3 M at dim 96), the fused CUDA kernel against the ATen
// reference path, with the step's peak memory. Only the tensors that hold
// 8-bit state (at least 4096 values) take part, so both paths time the same
// work (the small rest would go to ATen's fp32 fused AdamW in one and op by
// op in the other).
//
//   flat_bench adamw8bit                    # fp32 parameters
//   flat_bench adamw8bit --precision bf16 --steps 50
//
// Timing: median of --steps steps after --warmup, each bracketed by device
// synchronisation. Bytes per value of the fused step: parameter read and
// write, gradient read, both moments' codes read and written.
#include "flat/bench/adamw8bit_benchmark.h"

#include <algorithm>
#include <chrono>
#include <cstdio>

#include <torch/torch.h>

#include "flat/bench/timing.h"
#include "flat/core/device_memory.h"
#include "flat/core/error.h"
#include "flat/model/scene_decoder.h"
#include "flat/primitives/head_channels.h"
#include "flat/optim/adamw.h"

namespace flat::bench {
namespace {


struct StepTiming {
  double median_ms = 0, peak_gib = 0;
};

StepTiming time_steps(std::vector<std::pair<std::string, at::Tensor>> params, bool fused,
                      const AdamW8bitBenchOptions& o) {
  optim::AdamWOptions ao;
  ao.state_bits = 8;
  ao.fused = fused;  // both kernels, or the ATen ops throughout
  ao.fused_8bit = fused;
  optim::AdamW opt(params, ao);
  const auto device = params.front().second.device();
  for (int i = 0; i < o.warmup; ++i) opt.step(1e-4);
  torch::cuda::synchronize();
  reset_peak_memory(device);
  std::vector<double> ms;
  for (int i = 0; i < o.steps; ++i) {
    const double t0 = now_ms();
    opt.step(1e-4);
    torch::cuda::synchronize();
    ms.push_back(now_ms() - t0);
  }
  FLAT_CHECK(!fused || opt.fused_8bit_updates() > 0, "flat_bench adamw8bit: the fused kernel was not used");
  std::sort(ms.begin(), ms.end());
  return {ms[ms.size() / 2], peak_memory_gib(device)};
}


}  // namespace

void run_adamw8bit_benchmark(const AdamW8bitBenchOptions& o) {
  FLAT_CHECK(torch::cuda::is_available(), "flat_bench adamw8bit: needs a CUDA device");
  FLAT_CHECK(optim::AdamW::fused_8bit_available(), "flat_bench adamw8bit: this build has no CUDA kernels");
  FLAT_CHECK(o.steps > 0 && o.warmup >= 0, "flat_bench adamw8bit: --steps must be positive");
  const auto dtype = o.dtype == "bf16" ? at::kBFloat16 : at::kFloat;
  model::SceneDecoderConfig cfg;
  cfg.vae.dim = o.dim;
  model::SceneDecoder decoder(cfg, primitives::triangle_channels("ray_centred"));
  decoder->to(torch::kCUDA, dtype);
  std::vector<std::pair<std::string, at::Tensor>> params;
  int64_t numel = 0, all = 0;
  torch::manual_seed(0);
  for (auto& [name, p] : decoder->named_parameters().pairs()) {
    all += p.numel();
    if (p.numel() < optim::AdamWOptions{}.min_8bit_numel) continue;
    p.mutable_grad() = torch::randn_like(p) * 1e-3;
    params.emplace_back(name, p);
    numel += p.numel();
  }
  std::printf("flat_bench adamw8bit: %zu tensors, %.2f M of the decoder's %.2f M parameters (%s), median of %d "
              "steps\n",
              params.size(), double(numel) / 1e6, double(all) / 1e6, o.dtype.c_str(), o.steps);
  // Each path updates the same parameters in turn (the values do not change the cost).
  const auto fused = time_steps(params, true, o);
  const auto aten = time_steps(params, false, o);
  const double bytes = double(numel) * (2.0 * double(at::elementSize(dtype)) + double(at::elementSize(dtype)) + 4.0);
  std::printf("  fused kernel  %8.3f ms  (%.0f GB/s of parameter, gradient and code traffic), peak %.2f GiB\n",
              fused.median_ms, bytes / (fused.median_ms * 1e6), fused.peak_gib);
  std::printf("  ATen ops      %8.3f ms  peak %.2f GiB\n", aten.median_ms, aten.peak_gib);
  std::printf("  speed-up      %8.2fx\n", aten.median_ms / fused.median_ms);
}

}  // namespace flat::bench
