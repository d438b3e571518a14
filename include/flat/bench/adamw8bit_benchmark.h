// One 8-bit AdamW step over the scene decoder's parameters (flat_bench
// adamw8bit): the fused CUDA kernel against the ATen reference, median time
// and peak memory.
// flat_bench's `adamw8bit` subcommand (apps/flat_bench/bench_adamw8bit.cpp) only
// parses its flags into these options and calls run_adamw8bit_benchmark.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace flat::bench {

struct AdamW8bitBenchOptions {
  std::string dtype = "fp32";
  int64_t dim = 96;
  int steps = 20, warmup = 3;
};

// Runs the benchmark and prints its report; throws flat::Error on bad options.
void run_adamw8bit_benchmark(const AdamW8bitBenchOptions& options);

}  // namespace flat::bench
