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
  const auto bad = [&](const std::string& what) -> Error { return Error(path + ": " + what); };
  std::string line;
  std::getline(in, line);
  if (line != "ply") throw bad("not a PLY file (first line is not 'ply')");
  int64_t n_vertex = -1, n_face = -1;
  std::string element;
  std::vector<std::string> vertex_props, face_props;
  bool format_ok = false;
  while (true) {
    if (!std::getline(in, line)) throw bad("header ends before 'end_header'");
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream ls(line);
    std::string word;
    ls >> word;
    if (word == "end_header") break;
    if (word == "comment" || word == "obj_info" || word.empty()) continue;
    if (word == "format") {
      std::string fmt, ver;
      ls >> fmt >> ver;
      if (fmt != "binary_little_endian") throw bad("format '" + fmt + "' not supported (need binary_little_endian)");
      format_ok = true;
    } else if (word == "element") {
      int64_t count = -1;
      ls >> element >> count;
      if (count < 0) throw bad("element '" + element + "': bad count");
      if (element == "vertex") n_vertex = count;
      else if (element == "face") n_face = count;
      else throw bad("unexpected element '" + element + "' (expected vertex and face)");
    } else if (word == "property") {
      std::string type;
      ls >> type;
      if (element == "vertex") {
        std::string name;
        ls >> name;
        vertex_props.push_back(type + " " + name);
      } else if (element == "face") {
        if (type == "list") {
          std::string count_t, index_t, name;
          ls >> count_t >> index_t >> name;
          if (count_t != "uchar" || (index_t != "int" && index_t != "uint"))
            throw bad("element 'face': list '" + name + "' must be 'list uchar int'");
          face_props.push_back("list:" + name);
        } else {
          std::string name;
          ls >> name;
          if (type != "float") throw bad("element 'face': property '" + name + "' must be float, is " + type);
          face_props.push_back(name);
        }
      } else {
        throw bad("property outside of an element");
      }
    } else {
      throw bad("unexpected header line '" + line + "'");
    }
  }
  if (!format_ok) throw bad("missing 'format' line");
  if (n_vertex < 0 || n_face < 0) throw bad("needs both 'element vertex' and 'element face'");
  // Files written before the vertex colours have x, y, z only; both layouts
  // carry the same data (the face properties are the source of the colours).
  const std::vector<std::string> xyz = {"float x", "float y", "float z"};
  std::vector<std::string> xyz_rgba = xyz;
  for (const char* p : kVertexColours) xyz_rgba.push_back(std::string("uchar ") + p);
  if (vertex_props != xyz && vertex_props != xyz_rgba)
    throw bad("element 'vertex': properties must be float x, y, z, optionally followed by uchar red, green, blue, "
              "alpha");
  const size_t vertex_bytes = vertex_props == xyz ? 3 * sizeof(float) : kVertexBytes;
  const std::vector<std::string> want = {"list:vertex_indices", "red", "green", "blue", "opacity", "sigma"};
  if (face_props != want)
    throw bad("element 'face': properties must be 'list uchar int vertex_indices' then float red, green, blue, "
              "opacity, sigma");
  std::vector<char> vertex_data(size_t(n_vertex) * vertex_bytes);
  in.read(vertex_data.data(), (std::streamsize)vertex_data.size());
  if (!in) throw bad("element 'vertex': file ends after fewer than " + std::to_string(n_vertex) + " vertices");
  std::vector<float> verts(3 * n_vertex);
  for (int64_t j = 0; j < n_vertex; ++j)
    std::memcpy(verts.data() + 3 * j, vertex_data.data() + size_t(j) * vertex_bytes, 3 * sizeof(float));
  primitives::TriangleSoup soup;
  soup.vertices = at::empty({n_face, 3, 3}, at::kFloat);
  soup.colors = at::empty({n_face, 3}, at::kFloat);
  soup.opacities = at::empty({n_face}, at::kFloat);
  soup.sigmas = at::empty({n_face}, at::kFloat);
  float* vp = soup.vertices.data_ptr<float>();
  float* cp = soup.colors.data_ptr<float>();
  float* op = soup.opacities.data_ptr<float>();
  float* sp = soup.sigmas.data_ptr<float>();
  char rec[1 + 12 + 20];
  for (int64_t i = 0; i < n_face; ++i) {
    in.read(rec, 1);
    if (!in) throw bad("element 'face': file ends at face " + std::to_string(i) + " of " + std::to_string(n_face));
    if ((unsigned char)rec[0] != 3)
      throw bad("element 'face' " + std::to_string(i) + ": has " + std::to_string((unsigned char)rec[0]) +
                " vertices, need 3");
    in.read(rec + 1, 32);
    if (!in) throw bad("element 'face': file ends at face " + std::to_string(i) + " of " + std::to_string(n_face));
    int32_t idx[3];
    float attr[5];
    std::memcpy(idx, rec + 1, sizeof(idx));
    std::memcpy(attr, rec + 13, sizeof(attr));
    for (int k = 0; k < 3; ++k) {
      if (idx[k] < 0 || idx[k] >= n_vertex)
        throw bad("element 'face' " + std::to_string(i) + ": vertex index " + std::to_string(idx[k]) +
                  " out of range [0, " + std::to_string(n_vertex) + ")");
      for (int d = 0; d < 3; ++d) vp[9 * i + 3 * k + d] = verts[3 * idx[k] + d];
    }
    for (int c = 0; c < 3; ++c) cp[3 * i + c] = attr[c];
    op[i] = attr[3];
    sp[i] = attr[4];
  }
  return soup;
}

}  // namespace flat::exporter
