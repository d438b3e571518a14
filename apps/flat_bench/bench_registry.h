// Each bench_<what>.cpp adds one CLI11 subcommand. The list is explicit (no
// static-initialiser registration, which static libraries can silently drop).
#pragma once
#include <functional>
#include <vector>

#include <CLI/CLI.hpp>

namespace flat::bench {

using AddSubcommand = std::function<void(CLI::App&)>;

// One declaration and one list entry per bench file; add yours in both places.
inline std::vector<AddSubcommand> registry() {
  return {};
}

}  // namespace flat::bench
