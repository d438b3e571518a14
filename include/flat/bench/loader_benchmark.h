// Training-loader throughput (flat_bench loader): batches/s and samples/s
// from frame files and from packed scenes, on synthetic scenes written to a
// temporary folder (removed on every way out) or on a dataset folder.
// flat_bench's `loader` subcommand (apps/flat_bench/bench_loader.cpp) only
// parses its flags into these options and calls run_loader_benchmark.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace flat::bench {

struct LoaderBenchOptions {
  std::string data;  // "" = synthesise
  int64_t scenes = 4, scene_frames = 25;
  std::string source_size = "216x384";
  std::string size = "176x320";
  int64_t frames = 17, targets = 17, batch = 1, workers = 2, prefetch = 4;
  int64_t batches = 20, warmup = 2;
  std::string mode = "both";  // files | packed | both
};

// Runs the benchmark and prints its report; throws flat::Error on bad options.
void run_loader_benchmark(const LoaderBenchOptions& options);

}  // namespace flat::bench
