// GLB export: round trip through our reader, the layout read independently
// from the file's JSON and binary chunks, y-up handling, and errors.
#include <cstring>
#include <fstream>

#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/export/srgb.h"
#include "flat/export/triangle_glb.h"
#include "support/process.h"
#include "render/render_scenes.h"
#include "test_support.h"

using flat::exporter::glb_export_available;
using flat::exporter::read_triangle_glb;
using flat::exporter::write_triangle_glb;

namespace {

flat::primitives::TriangleSoup soup_of(const flat::test::Soup& s) { return {s.vertices, s.colors, s.opacities, s.sigmas}; }

struct Glb {
  nlohmann::json json;
  std::string bin;
};

// The two chunks of a GLB, parsed by hand (not through tinygltf).
Glb split_glb(const std::string& bytes) {
  Glb g;
  REQUIRE(bytes.size() >= 20);
  REQUIRE(bytes.compare(0, 4, "glTF") == 0);
  uint32_t version, length, json_len, json_type;
  std::memcpy(&version, bytes.data() + 4, 4);
  std::memcpy(&length, bytes.data() + 8, 4);
  std::memcpy(&json_len, bytes.data() + 12, 4);
  std::memcpy(&json_type, bytes.data() + 16, 4);
  CHECK(version == 2);
  CHECK(length == bytes.size());
  REQUIRE(json_type == 0x4E4F534Au);  // "JSON"
  g.json = nlohmann::json::parse(bytes.substr(20, json_len));
  const size_t bin_at = 20 + json_len;
  REQUIRE(bytes.size() >= bin_at + 8);
  uint32_t bin_len, bin_type;
  std::memcpy(&bin_len, bytes.data() + bin_at, 4);
  std::memcpy(&bin_type, bytes.data() + bin_at + 4, 4);
  REQUIRE(bin_type == 0x004E4942u);  // "BIN"
  g.bin = bytes.substr(bin_at + 8, bin_len);
  return g;
}

// Float element i, component c of accessor `a` (tightly packed, as we write).
float accessor_float(const Glb& g, int a, size_t i, size_t c, size_t comps) {
  const auto& acc = g.json["accessors"][a];
  const auto& view = g.json["bufferViews"][acc["bufferView"].get<int>()];
  const size_t at = view.value("byteOffset", size_t(0)) + acc.value("byteOffset", size_t(0)) + (i * comps + c) * 4;
  float f;
  std::memcpy(&f, g.bin.data() + at, 4);
  return f;
}

}  // namespace

TEST_CASE("triangle glb: without tinygltf the functions say so", "[export][glb]") {
  if (glb_export_available()) FLAT_SKIP("built with tinygltf: nothing to check here");
  auto dir = flat::test::scratch_dir("triangle_glb_unavailable");
  auto s = flat::test::random_soup(3, torch::kFloat, 1);
  REQUIRE_THROWS_WITH(write_triangle_glb((dir / "a.glb").string(), soup_of(s)), FLAT_CONTAINS("built without tinygltf"));
  REQUIRE_THROWS_WITH(read_triangle_glb((dir / "a.glb").string()), FLAT_CONTAINS("the PLY export still works"));
}

TEST_CASE("triangle glb: write then read gives the same soup", "[export][glb]") {
  if (!glb_export_available()) FLAT_SKIP("built without tinygltf (Debian libtinygltf-dev)");
  auto dir = flat::test::scratch_dir("triangle_glb_roundtrip");
  auto s = flat::test::random_soup(41, torch::kFloat, 5);
  s.colors[0] = torch::tensor({0.0f, 1.0f, 0.02f});  // both ends and the linear toe of the sRGB curve
  s.opacities[1] = 1.0f;
  const auto path = (dir / "soup.glb").string();
  write_triangle_glb(path, soup_of(s));
  auto r = read_triangle_glb(path);
  REQUIRE(r.vertices.sizes() == s.vertices.sizes());
  REQUIRE(r.colors.sizes() == s.colors.sizes());
  REQUIRE(r.opacities.sizes() == s.opacities.sizes());
  REQUIRE(r.sigmas.sizes() == s.sigmas.sizes());
  // The y-up rotation is undone exactly (its matrix holds only 0 and +-1).
  CHECK(torch::equal(r.vertices, s.vertices));
  // sRGB -> linear -> sRGB in float.
  CHECK((r.colors - s.colors).abs().max().item<float>() < 2e-6f);
  CHECK(torch::equal(r.opacities, s.opacities));
  CHECK(torch::equal(r.sigmas, s.sigmas));
  // No temp file left beside the target.
  int files = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) files += e.is_regular_file() ? 1 : 0;
  CHECK(files == 1);
}

TEST_CASE("triangle glb: the file holds the documented layout", "[export][glb]") {
  if (!glb_export_available()) FLAT_SKIP("built without tinygltf (Debian libtinygltf-dev)");
  auto dir = flat::test::scratch_dir("triangle_glb_layout");
  const int64_t n = 6;
  auto s = flat::test::random_soup(n, torch::kFloat, 9);
  const auto path = (dir / "soup.glb").string();
  write_triangle_glb(path, soup_of(s));
  const Glb g = split_glb(flat::test::read_file(path));
  const auto& j = g.json;
  CHECK(j["asset"]["version"] == "2.0");
  CHECK(j["asset"]["generator"] == "FLAT-C++");
  REQUIRE(j["meshes"].size() == 1);
  REQUIRE(j["meshes"][0]["primitives"].size() == 1);
  const auto& prim = j["meshes"][0]["primitives"][0];
  CHECK(prim.value("mode", 4) == 4);
  const int pos = prim["attributes"]["POSITION"], col = prim["attributes"]["COLOR_0"];
  const int sig = prim["attributes"]["_SIGMA"], idx = prim["indices"];
  const auto& acc = j["accessors"];
  CHECK(acc[pos]["type"] == "VEC3");
  CHECK(acc[pos]["componentType"] == 5126);
  CHECK(acc[pos]["count"] == 3 * n);
  CHECK(acc[col]["type"] == "VEC4");
  CHECK(acc[col]["componentType"] == 5126);
  CHECK(acc[sig]["type"] == "SCALAR");
  CHECK(acc[sig]["componentType"] == 5126);
  CHECK(acc[idx]["componentType"] == 5125);
  CHECK(acc[idx]["count"] == 3 * n);
  // POSITION min/max are the extremes of the vertices (world coordinates as is).
  const auto flat_v = s.vertices.reshape({-1, 3});
  for (int d = 0; d < 3; ++d) {
    CHECK(acc[pos]["min"][d].get<double>() == Approx(flat_v.select(1, d).min().item<double>()));
    CHECK(acc[pos]["max"][d].get<double>() == Approx(flat_v.select(1, d).max().item<double>()));
  }
  // Each corner carries its face's linear colour, opacity and sigma; positions as is.
  for (int64_t i = 0; i < n; ++i)
    for (int64_t k = 0; k < 3; ++k) {
      const size_t v = size_t(3 * i + k);
      for (int c = 0; c < 3; ++c) {
        const float srgb = s.colors[i][c].item<float>();
        CHECK(accessor_float(g, col, v, size_t(c), 4) == Approx(flat::exporter::srgb_to_linear(srgb)).margin(1e-6));
        CHECK(accessor_float(g, pos, v, size_t(c), 3) == s.vertices[i][k][c].item<float>());
      }
      CHECK(accessor_float(g, col, v, 3, 4) == s.opacities[i].item<float>());
      CHECK(accessor_float(g, sig, v, 0, 1) == s.sigmas[i].item<float>());
    }
  // A mid-grey display value is about 0.214 linear (not 0.5).
  CHECK(flat::exporter::srgb_to_linear(0.5f) == Approx(0.21404).margin(1e-4));
  const auto& mat = j["materials"][prim["material"].get<int>()];
  CHECK(mat["alphaMode"] == "BLEND");
  CHECK(mat["doubleSided"] == true);
  CHECK(mat["extensions"].contains("KHR_materials_unlit"));
  CHECK(j["extensionsUsed"].dump().find("KHR_materials_unlit") != std::string::npos);
  // One root node with the 180-degree rotation about x (OpenCV world -> y-up).
  const auto& roots = j["scenes"][j.value("scene", 0)]["nodes"];
  REQUIRE(roots.size() == 1);
  const auto& node = j["nodes"][roots[0].get<int>()];
  CHECK(node["mesh"] == 0);
  CHECK(node["rotation"] == nlohmann::json({1.0, 0.0, 0.0, 0.0}));
}

TEST_CASE("triangle glb: the reader applies the node transform of other files", "[export][glb]") {
  if (!glb_export_available()) FLAT_SKIP("built without tinygltf (Debian libtinygltf-dev)");
  auto dir = flat::test::scratch_dir("triangle_glb_yup");
  auto s = flat::test::random_soup(4, torch::kFloat, 3);
  const auto ours = (dir / "ours.glb").string();
  write_triangle_glb(ours, soup_of(s));
  // Same file with an identity rotation: its positions are then y-up world
  // coordinates, which read back flipped into our y-down world.
  std::string bytes = flat::test::read_file(ours);
  const std::string from = "\"rotation\":[1.0,0.0,0.0,0.0]", to = "\"rotation\":[0.0,0.0,0.0,1.0]";
  const size_t at = bytes.find(from);
  REQUIRE(at != std::string::npos);
  bytes.replace(at, from.size(), to);
  const auto plain = (dir / "plain.glb").string();
  std::ofstream(plain, std::ios::binary) << bytes;
  auto r = read_triangle_glb(plain);
  auto flip = torch::tensor({1.0f, -1.0f, -1.0f});
  CHECK(torch::equal(r.vertices, s.vertices * flip));
}

TEST_CASE("triangle glb: bad input is reported", "[export][glb]") {
  if (!glb_export_available()) FLAT_SKIP("built without tinygltf (Debian libtinygltf-dev)");
  auto dir = flat::test::scratch_dir("triangle_glb_errors");
  const auto out = (dir / "x.glb").string();
  auto s = flat::test::random_soup(3, torch::kFloat, 4);
  REQUIRE_THROWS_WITH(write_triangle_glb(out, {s.vertices.view({3, 9}), s.colors, s.opacities, s.sigmas}),
                      FLAT_CONTAINS("vertices"));
  REQUIRE_THROWS_WITH(write_triangle_glb(out, {s.vertices, s.colors.narrow(0, 0, 2), s.opacities, s.sigmas}),
                      FLAT_CONTAINS("colors"));
  REQUIRE_THROWS_WITH(write_triangle_glb(out, {s.vertices, torch::rand({3, 4, 3}), s.opacities, s.sigmas}),
                      FLAT_CONTAINS("colors"));
  REQUIRE_THROWS_WITH(write_triangle_glb(out, {s.vertices, s.colors, s.opacities.view({3, 1}), s.sigmas}),
                      FLAT_CONTAINS("opacities"));
  REQUIRE_THROWS_WITH(write_triangle_glb(out, {s.vertices, s.colors, s.opacities, s.sigmas.narrow(0, 0, 1)}),
                      FLAT_CONTAINS("sigmas"));
  REQUIRE_THROWS_WITH(write_triangle_glb(out, {torch::zeros({0, 3, 3}), torch::zeros({0, 3}), torch::zeros({0}),
                                               torch::zeros({0})}),
                      FLAT_CONTAINS("no triangles"));
  auto nan = s.vertices.clone();
  nan[1][2][0] = std::numeric_limits<float>::quiet_NaN();
  REQUIRE_THROWS_WITH(write_triangle_glb(out, {nan, s.colors, s.opacities, s.sigmas}), FLAT_CONTAINS("vertices"));
  CHECK(!std::filesystem::exists(out));

  REQUIRE_THROWS_WITH(read_triangle_glb((dir / "missing.glb").string()), FLAT_CONTAINS("missing.glb"));
  const auto good = (dir / "good.glb").string();
  write_triangle_glb(good, soup_of(s));
  const std::string bytes = flat::test::read_file(good);
  const auto cut = (dir / "truncated.glb").string();
  std::ofstream(cut, std::ios::binary) << bytes.substr(0, bytes.size() - 40);
  REQUIRE_THROWS_WITH(read_triangle_glb(cut), FLAT_CONTAINS("truncated.glb"));
  const auto text = (dir / "text.glb").string();
  std::ofstream(text) << "ply\nformat binary_little_endian 1.0\n";
  REQUIRE_THROWS_WITH(read_triangle_glb(text), FLAT_CONTAINS("text.glb: cannot read GLB"));
}
