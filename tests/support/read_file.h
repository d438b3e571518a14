// A whole file as bytes, for tests that compare what a writer left on disk.
#pragma once
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

namespace flat::test {

// The bytes of `path` ("" when it cannot be opened).
inline std::string read_file(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

}  // namespace flat::test
