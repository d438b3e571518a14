// Small helpers shared by the test executables.
#pragma once
#include <filesystem>
#include <string>

#include <torch/torch.h>

#include "catch.h"

namespace flat::test {

// A fresh, empty scratch folder under the build tree (or $FLAT_TEST_TMP).
inline std::filesystem::path scratch_dir(const std::string& name) {
  const char* env = std::getenv("FLAT_TEST_TMP");
  std::filesystem::path root = env ? env : std::filesystem::temp_directory_path() / "flat_test_tmp";
  auto dir = root / name;
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

inline bool cuda_available() { return torch::cuda::is_available(); }

// Relative error ||a - b|| / max(||b||, tiny), computed in double.
inline double rel_error(const torch::Tensor& a, const torch::Tensor& b) {
  auto ad = a.to(torch::kDouble).cpu();
  auto bd = b.to(torch::kDouble).cpu();
  double den = std::max(bd.norm().item<double>(), 1e-30);
  return (ad - bd).norm().item<double>() / den;
}

}  // namespace flat::test

#define FLAT_REQUIRE_CUDA()                                       \
  do {                                                            \
    if (!flat::test::cuda_available()) FLAT_SKIP("no CUDA device"); \
  } while (0)
