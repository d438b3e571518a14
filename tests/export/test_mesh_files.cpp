// The opaque mesh's GLB, PLY and OBJ: counts, indices and colours as written.
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include "flat/export/mesh_files.h"
#include "flat/export/srgb.h"
#include "flat/export/triangle_glb.h"
#include "support/read_file.h"
#include "test_support.h"

namespace fs = std::filesystem;
using flat::test::read_file;
using namespace flat;

namespace {

// A square of two triangles sharing an edge, with distinct vertex colours.
primitives::IndexedMesh square() {
  return {torch::tensor(std::vector<float>{0, 0, 1, 1, 0, 1, 1, 1, 1, 0, 1, 1}).reshape({4, 3}),
          torch::tensor(std::vector<float>{1, 0, 0, 0, 1, 0, 0, 0, 1, 0.5f, 0.5f, 0.5f}).reshape({4, 3}),
          torch::tensor(std::vector<int64_t>{0, 1, 2, 0, 2, 3}).reshape({2, 3})};
}

}  // namespace

TEST_CASE("mesh PLY: shared vertices with byte colours, faces as int lists", "[export]") {
  const auto dir = test::scratch_dir("mesh_ply");
  const auto path = dir / "mesh.ply";
  exporter::write_mesh_ply(path.string(), square());
  const std::string bytes = read_file(path);
  const auto end = bytes.find("end_header\n");
  REQUIRE(end != std::string::npos);
  const std::string header = bytes.substr(0, end);
  CHECK_THAT(header, FLAT_CONTAINS("element vertex 4"));
  CHECK_THAT(header, FLAT_CONTAINS("element face 2"));
  const size_t body = end + 11;
  REQUIRE(bytes.size() == body + 4 * 15 + 2 * 13);
  // Vertex 1: (1,0,1), green.
  float xyz[3];
  std::memcpy(xyz, bytes.data() + body + 15, 12);
  CHECK(xyz[0] == 1.f);
  CHECK(xyz[2] == 1.f);
  CHECK(uint8_t(bytes[body + 15 + 13]) == 255);
  CHECK(uint8_t(bytes[body + 15 + 12]) == 0);
  // Face 1: 3, then 0 2 3.
  const size_t f1 = body + 4 * 15 + 13;
  CHECK(uint8_t(bytes[f1]) == 3);
  int32_t idx[3];
  std::memcpy(idx, bytes.data() + f1 + 1, 12);
  CHECK(idx[0] == 0);
  CHECK(idx[1] == 2);
  CHECK(idx[2] == 3);
}

TEST_CASE("mesh OBJ: v x y z r g b lines and 1-based faces", "[export]") {
  const auto dir = test::scratch_dir("mesh_obj");
  const auto path = dir / "mesh.obj";
  exporter::write_mesh_obj(path.string(), square());
  std::istringstream in(read_file(path));
  std::string line;
  int vertices = 0, faces = 0;
  std::vector<std::string> face_lines;
  while (std::getline(in, line)) {
    if (line.rfind("v ", 0) == 0) {
      ++vertices;
      std::istringstream v(line.substr(2));
      double x, y, z, r, g, b;
      REQUIRE(static_cast<bool>(v >> x >> y >> z >> r >> g >> b));
      if (vertices == 3) CHECK(b == Approx(1.0));
    }
    if (line.rfind("f ", 0) == 0) {
      ++faces;
      face_lines.push_back(line);
    }
  }
  CHECK(vertices == 4);
  CHECK(faces == 2);
  CHECK(face_lines[1] == "f 1 3 4");
}

TEST_CASE("mesh GLB: indexed, opaque, linear VEC3 colours; bad meshes are refused", "[export]") {
  if (!exporter::glb_export_available()) FLAT_SKIP("built without tinygltf");
  const auto dir = test::scratch_dir("mesh_glb");
  const auto path = dir / "mesh.glb";
  exporter::write_mesh_glb(path.string(), square());
  const std::string bytes = read_file(path);
  REQUIRE(bytes.compare(0, 4, "glTF") == 0);
  uint32_t json_len = 0;
  std::memcpy(&json_len, bytes.data() + 12, 4);
  const auto j = nlohmann::json::parse(bytes.substr(20, json_len));
  const auto& prim = j["meshes"][0]["primitives"][0];
  // OPAQUE is glTF's default, which writers may leave out; BLEND (the soup's) must not appear.
  CHECK(j["materials"][0].value("alphaMode", std::string("OPAQUE")) == "OPAQUE");
  CHECK(j["accessors"][prim["attributes"]["POSITION"].get<int>()]["count"] == 4);
  CHECK(j["accessors"][prim["attributes"]["COLOR_0"].get<int>()]["type"] == "VEC3");
  CHECK(j["accessors"][prim["indices"].get<int>()]["count"] == 6);
  // Bad input: an index out of range, NaN positions; nothing is left behind.
  auto bad = square();
  bad.faces[1][2] = 9;
  REQUIRE_THROWS_WITH(exporter::write_mesh_glb((dir / "bad.glb").string(), bad), FLAT_CONTAINS("out of range"));
  auto nan = square();
  nan.vertices[0][0] = NAN;
  REQUIRE_THROWS_WITH(exporter::write_mesh_ply((dir / "nan.ply").string(), nan), FLAT_CONTAINS("vertices"));
  CHECK_FALSE(fs::exists(dir / "bad.glb"));
  CHECK_FALSE(fs::exists(dir / "nan.ply"));
}
