// flat_bench: timing and peak-memory benchmarks at the paper's sizes.
// One subcommand per benchmarked component, each in its own file here
// (bench_<what>.cpp) registering itself through bench_registry.h.
#include <CLI/CLI.hpp>
#include <spdlog/cfg/env.h>
#include <spdlog/spdlog.h>

#include "bench_registry.h"
#include "flat/core/cli.h"
#include "flat/core/error.h"

int main(int argc, char** argv) {
  spdlog::cfg::load_env_levels();  // SPDLOG_LEVEL=debug: e.g. the rasterizer's per-view workload
  CLI::App app{"flat_bench: time FLAT components (median of repeats after warm-up, peak memory)"};
  std::string log_level = "info";
  flat::cli::add_common(app, "flat_bench", log_level);
  // An explicit --log-level replaces SPDLOG_LEVEL, before any subcommand runs.
  app.parse_complete_callback([&] {
    if (app.count("--log-level") > 0) flat::cli::start_logging(log_level);
  });
  app.require_subcommand(1);
  for (const auto& add : flat::bench::registry()) add(app);
  // The subcommands run in CLI11 callbacks, i.e. inside parse, so the restart
  // comes first (also for --help, which costs a start-up); old flag names
  // before it, so that the restarted process reads the new ones.
  flat::cli::rename_old_names(app, argc, argv);
  flat::cli::restart_with_sleeping_openmp_threads(argv);
  // Errors are mapped here.
  return flat::cli::run([&] {
    try {
      app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
      return app.exit(e) == 0 ? flat::cli::kExitOk : flat::cli::kExitUsage;
    }
    return 0;
  });
}
