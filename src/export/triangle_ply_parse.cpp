// Torch-free reader of triangle PLYs (include/flat/export/triangle_ply_parse.h).
#include "flat/export/triangle_ply_parse.h"

#include <cstdio>
#include <cstring>
#include <sstream>

#include "flat/core/error.h"

namespace flat::exporter {
namespace {

constexpr const char* kVertexColours[] = {"red", "green", "blue", "alpha"};
constexpr size_t kVertexBytes = 3 * sizeof(float) + 4;  // x, y, z, red, green, blue, alpha
constexpr size_t kFaceBytes = 1 + 3 * sizeof(int32_t) + 5 * sizeof(float);

std::string bytes_text(double bytes) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.0f", bytes);
  return buf;
}

}  // namespace

PlyTriangles parse_triangle_ply(std::istream& in, const std::string& path) {
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
      if (!ls || count < 0) throw bad("element '" + element + "': bad count");
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
  // The counts must fit the bytes that follow: checked before any allocation.
  const auto header_end = in.tellg();
  in.seekg(0, std::ios::end);
  const auto file_end = in.tellg();
  in.seekg(header_end);
  if (header_end < 0 || file_end < 0 || !in) throw bad("cannot determine the file size");
  const double available = double(file_end - header_end);
  const double needed = double(n_vertex) * double(vertex_bytes) + double(n_face) * double(kFaceBytes);
  if (needed > available) {
    const bool vertices_alone = double(n_vertex) * double(vertex_bytes) > available;
    throw bad(std::string(vertices_alone ? "element 'vertex'" : "element 'face'") + ": the header declares " +
              std::to_string(n_vertex) + " vertices and " + std::to_string(n_face) + " faces (" + bytes_text(needed) +
              " bytes) but only " + bytes_text(available) + " bytes follow the header");
  }
  std::vector<char> vertex_data(size_t(n_vertex) * vertex_bytes);
  in.read(vertex_data.data(), (std::streamsize)vertex_data.size());
  if (!in) throw bad("element 'vertex': file ends after fewer than " + std::to_string(n_vertex) + " vertices");
  std::vector<float> verts(size_t(3 * n_vertex));
  for (int64_t j = 0; j < n_vertex; ++j)
    std::memcpy(verts.data() + 3 * j, vertex_data.data() + size_t(j) * vertex_bytes, 3 * sizeof(float));
  PlyTriangles soup;
  soup.faces = n_face;
  soup.vertices.resize(size_t(n_face) * 9);
  soup.colors.resize(size_t(n_face) * 3);
  soup.opacities.resize(size_t(n_face));
  soup.sigmas.resize(size_t(n_face));
  float* vp = soup.vertices.data();
  float* cp = soup.colors.data();
  float* op = soup.opacities.data();
  float* sp = soup.sigmas.data();
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
