// Scratch folders for the data tests: a fresh name per call (pid + counter), so
// test::scratch_dir never has to delete an old tree (std::filesystem::remove_all
// resolves to libtorch's bundled copy, which crashes on non-empty folders).
#pragma once
#include <atomic>
#include <string>

#include <unistd.h>

#include "test_support.h"

namespace flat::test {

inline std::filesystem::path fresh_dir(const std::string& name) {
  static std::atomic<int> counter{0};
  return scratch_dir(name + "_" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
}

}  // namespace flat::test
