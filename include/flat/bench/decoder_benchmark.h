// Scene decoder forward time and memory (flat_bench decoder): full sequence
// and streaming, with an optional per-block breakdown.
// flat_bench's `decoder` subcommand (apps/flat_bench/bench_decoder.cpp) only
// parses its flags into these options and calls run_decoder_benchmark.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "flat/model/scene_decoder.h"

namespace flat::bench {

struct DecoderBenchOptions {
  std::vector<int64_t> frames{13, 21};
  int64_t height = 54, width = 96;  // latent size (x8 = video)
  std::string mode = "both";        // full | streaming | both
  std::string camera = "precomputed";
  std::string heads = "independent";
  int64_t stream_trunk_frames = model::SceneDecoderConfig{}.stream_trunk_frames;
  std::string dtype = "bf16";
  std::string device = "auto";
  int64_t dim = 96;
  int repeats = 5, warmup = 2;
  bool channels_last = true, fused_norm = true, breakdown = false, ops = false, cudnn_benchmark = true;
  std::string conv = "auto";  // auto | cudnn | a CUTLASS configuration name
};

// Runs the benchmark and prints its report; throws flat::Error on bad options.
void run_decoder_benchmark(const DecoderBenchOptions& options);

}  // namespace flat::bench
