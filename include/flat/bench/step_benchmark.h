// Times the training step of a config (flat_bench train): warm-up steps, then
// timed steps, each phase ended by a device synchronisation so the time can be
// attributed (train/train_step.h), plus the loader's wait and the optimiser; and the
// peak device memory. The numbers of docs/benchmarks.md come from here.
#pragma once
#include <cstdint>
#include <string>

#include "flat/train/train_config.h"
#include "flat/train/train_step.h"

namespace flat::bench {

struct StepBenchmark {
  int64_t steps = 0;
  double step_ms = 0;        // median of whole steps, synchronised phases included
  double unsynced_step_ms = 0;  // median of steps run as training runs them (no phase syncs)
  double data_ms = 0, decode_forward_ms = 0, render_forward_ms = 0, loss_forward_ms = 0;
  double render_loss_backward_ms = 0, decoder_backward_ms = 0, optimiser_ms = 0;  // medians
  double lpips_ms = 0;       // LPIPS forward + backward alone on the step's views (0 when off)
  double peak_gib = 0;       // peak CUDA memory (0 on the CPU)
  int64_t triangles = 0;     // rendered per step
  double parameters_m = 0;
  std::string table() const;  // Markdown rows
};

// cfg.data must point at scenes with latents of cfg's window and size.
// profile (CUDA only): after the timed steps, one more step and one LPIPS
// fwd+bwd run under the Kineto profiler, and their GPU kernels are printed
// by phase and by class (bench/gpu_profile.h).
StepBenchmark benchmark_training(const train::TrainConfig& cfg, int64_t warmup, int64_t steps, bool profile = false);

// Writes an LPIPS weights file of the right shapes with random values (for
// timing only: the cost does not depend on the values). Returns its path.
std::string write_random_lpips_weights(const std::string& path, uint64_t seed);

}  // namespace flat::bench
