// The triangle PLY (triangle_ply.h, docs/formats.md) parsed into plain arrays,
// without libtorch: every check of the format lives here, so that the fuzz
// target (fuzz/fuzz_triangle_ply.cpp) exercises exactly what the tools run.
#pragma once
#include <cstdint>
#include <istream>
#include <string>
#include <vector>

namespace flat::exporter {

struct PlyTriangles {
  int64_t faces = 0;
  std::vector<float> vertices;   // (faces, 3, 3) row-major
  std::vector<float> colors;     // (faces, 3)
  std::vector<float> opacities;  // (faces)
  std::vector<float> sigmas;     // (faces)
};

// Reads a binary_little_endian triangle PLY from `in` (opened in binary mode);
// `label` (the file) starts every error message. Counts in the header are
// checked against the bytes that follow before anything is allocated, so a
// header that claims 4e9 faces is an error, not an allocation.
PlyTriangles parse_triangle_ply(std::istream& in, const std::string& label);

}  // namespace flat::exporter
