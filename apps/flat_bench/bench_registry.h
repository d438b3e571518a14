// Each bench_<what>.cpp adds one CLI11 subcommand. The list is explicit (no
// static-initialiser registration, which static libraries can silently drop).
#pragma once
#include <functional>
#include <vector>

#include <CLI/CLI.hpp>

namespace flat::bench {

using AddSubcommand = std::function<void(CLI::App&)>;

void add_decoder(CLI::App& app);  // bench_decoder.cpp
void add_raster(CLI::App& app);   // bench_raster.cpp
void add_loader(CLI::App& app);   // bench_loader.cpp

inline std::vector<AddSubcommand> registry() {
  return {
#ifdef FLAT_BENCH_HAS_DECODER
      add_decoder,
#endif
#ifdef FLAT_BENCH_HAS_RASTER
      add_raster,
#endif
#ifdef FLAT_BENCH_HAS_LOADER
      add_loader,
#endif
  };
}

}  // namespace flat::bench
