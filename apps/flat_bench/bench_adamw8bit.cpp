// flat_bench adamw8bit: one 8-bit AdamW step over the scene decoder's
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
#include <memory>

#include <CLI/CLI.hpp>

#include "bench_registry.h"
#include "flat/bench/adamw8bit_benchmark.h"
#include "flat/core/cli.h"

namespace flat::bench {

void add_adamw8bit(CLI::App& app) {
  auto o = std::make_shared<AdamW8bitBenchOptions>();
  auto* cmd = app.add_subcommand("adamw8bit", "8-bit AdamW step on the scene decoder's parameters: fused CUDA "
                                               "kernel vs ATen ops");
  cli::add_precision(*cmd, o->dtype)->description("compute dtype of the parameters (and gradients): fp32 | bf16");
  cli::add_old_name(*cmd, "--dtype", "--precision");
  cmd->add_option("--dim", o->dim, "decoder base width (96 = paper)")->capture_default_str();
  cmd->add_option("--steps", o->steps, "timed steps")->capture_default_str();
  cmd->add_option("--warmup", o->warmup, "untimed steps first")->capture_default_str();
  cmd->callback([o] { run_adamw8bit_benchmark(*o); });
}

}  // namespace flat::bench
