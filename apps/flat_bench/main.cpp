// flat_bench: timing and peak-memory benchmarks at the paper's sizes.
// One subcommand per benchmarked component, each in its own file here
// (bench_<what>.cpp) registering itself through bench_registry.h.
#include <CLI/CLI.hpp>
#include <spdlog/cfg/env.h>
#include <spdlog/spdlog.h>

#include "bench_registry.h"
#include "flat/core/error.h"

int main(int argc, char** argv) {
  spdlog::cfg::load_env_levels();  // SPDLOG_LEVEL=debug: e.g. the rasterizer's per-view workload
  CLI::App app{"flat_bench: time FLAT components (median of repeats after warm-up, peak memory)"};
  app.require_subcommand(1);
  for (const auto& add : flat::bench::registry()) add(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (...) {
    return flat::report_current_error();
  }
  return 0;
}
