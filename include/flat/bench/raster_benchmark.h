// The rasterizer benchmark (flat_bench raster): forward and forward+backward
// time (median), peak GPU memory and each view's load, for triangles, 3DGS or
// 2DGS on the anchor workloads, our room scenes or a PLY + cameras JSON.
// flat_bench's `raster` subcommand (apps/flat_bench/bench_raster.cpp) only
// parses its flags into these options and calls run_raster_benchmark.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace flat::bench {

struct RasterBenchOptions {
  std::vector<std::string> workloads = {"anchor-large", "anchor-small"};
  std::string ply, cams, window = "flat", device = "auto", write_dir;
  std::vector<std::string> representations = {"triangles"};
  int repeats = 5, views_per_bin = 2;
  uint64_t seed = 0;
  bool profile = false;
};

// Runs the benchmark and prints its Markdown rows; throws flat::Error on bad options.
void run_raster_benchmark(const RasterBenchOptions& options);

}  // namespace flat::bench
