// Each bench_<what>.cpp adds one CLI11 subcommand. The list is explicit (no
// static-initialiser registration, which static libraries can silently drop).
#pragma once
#include <functional>
#include <vector>

#include <CLI/CLI.hpp>

namespace flat::bench {

using AddSubcommand = std::function<void(CLI::App&)>;

void add_adamw8bit(CLI::App& app);  // bench_adamw8bit.cpp
void add_decoder(CLI::App& app);  // bench_decoder.cpp
void add_loader(CLI::App& app);   // bench_loader.cpp
void add_raster(CLI::App& app);   // bench_raster.cpp
void add_train(CLI::App& app);    // bench_train.cpp

// One declaration and one list entry per bench file; add yours in both places.
inline std::vector<AddSubcommand> registry() {
  return {add_adamw8bit, add_decoder, add_loader, add_raster, add_train};
}

}  // namespace flat::bench
