// Reading the source tree as text, for the layering checks (module_map.h,
// function_length.h): no compiler, no torch.
#pragma once
#include <filesystem>
#include <string>
#include <vector>

namespace flat::layering {

// The whole file; throws std::runtime_error naming it when it cannot be read.
std::string read_text(const std::filesystem::path& path);

// C++ and CUDA sources and headers (.h .hpp .cuh .inl .cpp .cc .cu) under
// `dir`, recursively, sorted; none when `dir` is not a folder.
std::vector<std::filesystem::path> code_files(const std::filesystem::path& dir);

}  // namespace flat::layering
