// Binary little-endian PLY reader/writer for triangle soups (docs/formats.md).
#include "flat/export/triangle_ply.h"

#include <cmath>
#include <cstring>
#include <fstream>
#include <sstream>
#include <vector>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/export/triangle_ply_parse.h"

namespace flat::exporter {
namespace {

constexpr const char* kFaceFloats[] = {"red", "green", "blue", "opacity", "sigma"};
constexpr const char* kVertexColours[] = {"red", "green", "blue", "alpha"};
constexpr size_t kVertexBytes = 3 * sizeof(float) + 4;  // x, y, z, red, green, blue, alpha

// [0,1] -> 0..255, rounded; NaN -> 0 (the float face properties keep the value).
uint8_t to_byte(float x) {
  const float c = x > 0.f ? (x < 1.f ? x : 1.f) : 0.f;
  return uint8_t(std::lround(255.f * c));
}

bool little_endian_host() {
  const uint16_t one = 1;
  uint8_t b;
  std::memcpy(&b, &one, 1);
  return b == 1;
}

}  // namespace

void write_triangle_ply(const std::string& path, const primitives::TriangleSoup& soup) {
  check_shape(soup.vertices, {-1, 3, 3}, "triangle ply: vertices", "(N,3,3)");
  const int64_t n = soup.vertices.size(0);
  check_shape(soup.colors, {n, 3}, "triangle ply: colors", "(N,3)");
  check_shape(soup.opacities, {n}, "triangle ply: opacities", "(N)");
  check_shape(soup.sigmas, {n}, "triangle ply: sigmas", "(N)");
  FLAT_CHECK(little_endian_host(), "triangle ply: big-endian hosts are not supported");
  FLAT_CHECK(3 * n < (int64_t(1) << 31), "triangle ply: too many triangles for int vertex indices");
  const auto cpu = [](const at::Tensor& t) { return t.detach().to(at::kCPU, at::kFloat).contiguous(); };
  const at::Tensor v = cpu(soup.vertices), c = cpu(soup.colors), o = cpu(soup.opacities), s = cpu(soup.sigmas);
  const float* vp = v.data_ptr<float>();
  const float* cp = c.data_ptr<float>();
  const float* op = o.data_ptr<float>();
  const float* sp = s.data_ptr<float>();
  write_file_atomic(path, [&](std::ostream& out) {
    out << "ply\nformat binary_little_endian 1.0\ncomment FLAT triangle soup (docs/formats.md)\n"
        << "element vertex " << 3 * n << "\nproperty float x\nproperty float y\nproperty float z\n";
    for (const char* p : kVertexColours) out << "property uchar " << p << "\n";
    out << "element face " << n << "\nproperty list uchar int vertex_indices\n";
    for (const char* p : kFaceFloats) out << "property float " << p << "\n";
    out << "end_header\n";
    // Vertices: each face's colour repeated on its three corners, for readers
    // that only know vertex colours (Blender, MeshLab, trimesh).
    std::vector<char> vertex(kVertexBytes);
    for (int64_t i = 0; i < n; ++i) {
      const uint8_t rgba[4] = {to_byte(cp[3 * i]), to_byte(cp[3 * i + 1]), to_byte(cp[3 * i + 2]), to_byte(op[i])};
      for (int k = 0; k < 3; ++k) {
        std::memcpy(vertex.data(), vp + 9 * i + 3 * k, 3 * sizeof(float));
        std::memcpy(vertex.data() + 12, rgba, sizeof(rgba));
        out.write(vertex.data(), (std::streamsize)vertex.size());
      }
    }
    std::vector<char> face(1 + 3 * 4 + 5 * 4);
    for (int64_t i = 0; i < n; ++i) {
      face[0] = 3;
      const int32_t idx[3] = {int32_t(3 * i), int32_t(3 * i + 1), int32_t(3 * i + 2)};
      const float attr[5] = {cp[3 * i], cp[3 * i + 1], cp[3 * i + 2], op[i], sp[i]};
      std::memcpy(face.data() + 1, idx, sizeof(idx));
      std::memcpy(face.data() + 13, attr, sizeof(attr));
      out.write(face.data(), (std::streamsize)face.size());
    }
  });
}

primitives::TriangleSoup read_triangle_ply(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  FLAT_CHECK(in.good(), path + ": cannot open triangle PLY");
  PlyTriangles p = parse_triangle_ply(in, path);
  const auto copy = [](std::vector<float>& v, at::IntArrayRef shape) {
    return at::from_blob(v.data(), shape, at::kFloat).clone();
  };
  primitives::TriangleSoup soup;
  soup.vertices = copy(p.vertices, {p.faces, 3, 3});
  soup.colors = copy(p.colors, {p.faces, 3});
  soup.opacities = copy(p.opacities, {p.faces});
  soup.sigmas = copy(p.sigmas, {p.faces});
  // The values docs/formats.md promises, checked here with the file's name
  // (the rasterizer would refuse them too, naming only its own inputs).
  const auto first_bad = [&](const at::Tensor& bad, const std::string& what) {
    const auto per_face = bad.dim() > 1 ? bad.flatten(1).any(1) : bad;
    const int64_t n = per_face.sum().item<int64_t>();
    if (n > 0)
      fail(path + ": " + std::to_string(n) + " face(s) with " + what + " (the first: face " +
           std::to_string(per_face.nonzero()[0][0].item<int64_t>()) + ")");
  };
  first_bad(~at::isfinite(soup.vertices), "a non-finite vertex coordinate");
  first_bad(~at::isfinite(soup.colors), "a non-finite colour");
  first_bad(~((soup.opacities >= 0) & (soup.opacities <= 1)), "opacity outside [0, 1]");
  first_bad(~((soup.sigmas > 0) & at::isfinite(soup.sigmas)), "sigma not a finite number > 0");
  return soup;
}

}  // namespace flat::exporter
