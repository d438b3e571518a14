// The opaque mesh as binary PLY and as OBJ with vertex colours
// (docs/formats.md, "Opaque mesh"). One file for both: the same walk over
// the same arrays, two spellings.
#include <cmath>
#include <cstring>
#include <vector>

#include <fmt/format.h>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "flat/export/mesh_files.h"

namespace flat::exporter {

namespace {

// The mesh as plain arrays: positions, colours clamped to [0,1], int32 faces.
struct MeshArrays {
  at::Tensor vt, ct, ft;  // CPU, contiguous: they own what the pointers show
  int64_t nv = 0, nf = 0;
  const float* v = nullptr;
  const float* c = nullptr;
  const int32_t* f = nullptr;
};

MeshArrays mesh_arrays(const std::string& path, const primitives::IndexedMesh& mesh) {
  primitives::check_mesh(mesh, path);
  FLAT_CHECK(mesh.num_vertices() < (int64_t(1) << 31), path + ": too many vertices for int indices");
  MeshArrays a;
  a.vt = mesh.vertices.detach().to(at::kCPU, at::kFloat).contiguous();
  a.ct = mesh.colors.detach().to(at::kCPU, at::kFloat).clamp(0, 1).contiguous();
  a.ft = mesh.faces.to(at::kCPU).to(at::kInt).contiguous();
  a.nv = a.vt.size(0);
  a.nf = a.ft.size(0);
  a.v = a.vt.data_ptr<float>();
  a.c = a.ct.data_ptr<float>();
  a.f = a.ft.data_ptr<int32_t>();
  return a;
}

uint8_t to_byte(float x) { return uint8_t(std::lround(255.f * x)); }

}  // namespace

void write_mesh_ply(const std::string& path, const primitives::IndexedMesh& mesh) {
  const auto a = mesh_arrays(path, mesh);
  write_file_atomic(path, [&](std::ostream& out) {
    out << "ply\nformat binary_little_endian 1.0\ncomment FLAT opaque mesh (docs/formats.md)\n"
        << "element vertex " << a.nv << "\nproperty float x\nproperty float y\nproperty float z\n"
        << "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        << "element face " << a.nf << "\nproperty list uchar int vertex_indices\nend_header\n";
    char vertex[15];
    for (int64_t i = 0; i < a.nv; ++i) {
      std::memcpy(vertex, a.v + 3 * i, 12);
      for (int k = 0; k < 3; ++k) vertex[12 + k] = char(to_byte(a.c[3 * i + k]));
      out.write(vertex, sizeof(vertex));
    }
    char face[13];
    face[0] = 3;
    for (int64_t i = 0; i < a.nf; ++i) {
      std::memcpy(face + 1, a.f + 3 * i, 12);
      out.write(face, sizeof(face));
    }
  });
}

void write_mesh_obj(const std::string& path, const primitives::IndexedMesh& mesh) {
  const auto a = mesh_arrays(path, mesh);
  write_file_atomic(path, [&](std::ostream& out) {
    out << "# FLAT opaque mesh (docs/formats.md): " << a.nv << " vertices, " << a.nf << " faces\n";
    fmt::memory_buffer b;
    for (int64_t i = 0; i < a.nv; ++i)
      fmt::format_to(std::back_inserter(b), "v {} {} {} {:.4f} {:.4f} {:.4f}\n", a.v[3 * i], a.v[3 * i + 1],
                     a.v[3 * i + 2], a.c[3 * i], a.c[3 * i + 1], a.c[3 * i + 2]);
    for (int64_t i = 0; i < a.nf; ++i)
      fmt::format_to(std::back_inserter(b), "f {} {} {}\n", a.f[3 * i] + 1, a.f[3 * i + 1] + 1, a.f[3 * i + 2] + 1);
    out.write(b.data(), std::streamsize(b.size()));
  });
}

}  // namespace flat::exporter
