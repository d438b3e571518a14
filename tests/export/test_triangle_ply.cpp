// Triangle soup PLY: round trip, vertex colours for other readers, the older
// layout without them, and clear errors on malformed files.
#include <cmath>
#include <cstring>
#include <fstream>

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/export/triangle_ply.h"
#include "render/render_scenes.h"
#include "support/read_file.h"
#include "test_support.h"

using flat::exporter::read_triangle_ply;
using flat::test::read_file;
using flat::exporter::write_triangle_ply;

TEST_CASE("triangle ply: write then read gives the same soup", "[export][ply]") {
  auto dir = flat::test::scratch_dir("triangle_ply_roundtrip");
  auto s = flat::test::random_soup(17, torch::kFloat, 4);
  const auto path = (dir / "soup.ply").string();
  write_triangle_ply(path, {s.vertices, s.colors, s.opacities, s.sigmas});
  auto r = read_triangle_ply(path);
  CHECK(torch::equal(r.vertices, s.vertices));
  CHECK(torch::equal(r.colors, s.colors));
  CHECK(torch::equal(r.opacities, s.opacities));
  CHECK(torch::equal(r.sigmas, s.sigmas));
}

TEST_CASE("triangle ply: malformed files are reported with file and element", "[export][ply]") {
  auto dir = flat::test::scratch_dir("triangle_ply_errors");
  const auto missing = (dir / "nope.ply").string();
  REQUIRE_THROWS_WITH(read_triangle_ply(missing), FLAT_CONTAINS("nope.ply"));
  auto s = flat::test::random_soup(3, torch::kFloat, 4);
  const auto good = (dir / "good.ply").string();
  write_triangle_ply(good, {s.vertices, s.colors, s.opacities, s.sigmas});
  const std::string bytes = read_file(good);
  const auto truncated = (dir / "truncated.ply").string();
  std::ofstream(truncated, std::ios::binary) << bytes.substr(0, bytes.size() - 10);
  REQUIRE_THROWS_WITH(read_triangle_ply(truncated), FLAT_CONTAINS("truncated.ply: element 'face'"));
  // A header that claims 4e9 faces over a short body: refused before allocating, with the figures.
  const auto huge = (dir / "huge.ply").string();
  std::string header = bytes.substr(0, bytes.find("end_header\n") + 11);
  const auto at = header.find("element face 3");
  REQUIRE(at != std::string::npos);
  header.replace(at, 14, "element face 4000000000");
  std::ofstream(huge, std::ios::binary) << header << bytes.substr(bytes.find("end_header\n") + 11);
  REQUIRE_THROWS_WITH(read_triangle_ply(huge),
                      FLAT_CONTAINS("huge.ply: element 'face'") && FLAT_CONTAINS("4000000000 faces") &&
                          FLAT_CONTAINS("bytes follow the header"));
  const auto ascii = (dir / "ascii.ply").string();
  std::ofstream(ascii) << "ply\nformat ascii 1.0\nelement vertex 0\nend_header\n";
  REQUIRE_THROWS_WITH(read_triangle_ply(ascii), FLAT_CONTAINS("binary_little_endian"));
  REQUIRE_THROWS_WITH(write_triangle_ply((dir / "x.ply").string(), {s.vertices.view({3, 9}), s.colors, s.opacities, s.sigmas}),
                      FLAT_CONTAINS("vertices"));
}

namespace {

template <class T>
void put(std::string& out, T value) {
  out.append(reinterpret_cast<const char*>(&value), sizeof(T));
}

}  // namespace

TEST_CASE("triangle ply: vertex colours are the face colours and opacity, quantised", "[export][ply]") {
  auto dir = flat::test::scratch_dir("triangle_ply_vertex_colours");
  auto s = flat::test::random_soup(9, torch::kFloat, 7);
  // Out-of-range values are clamped in the bytes (the float face properties keep them).
  s.colors[0] = torch::tensor({-0.2f, 1.3f, 0.5f});  // 127.5 rounds up to 128
  s.colors[1] = torch::tensor({0.0f, 1.0f, 0.25f});
  s.opacities[0] = 1.0f;
  s.opacities[1] = 0.0f;
  const auto path = (dir / "soup.ply").string();
  write_triangle_ply(path, {s.vertices, s.colors, s.opacities, s.sigmas});
  const std::string bytes = read_file(path);
  const std::string header_end = "end_header\n";
  const size_t body = bytes.find(header_end);
  REQUIRE(body != std::string::npos);
  const std::string header = bytes.substr(0, body);
  CHECK(header.find("element vertex 27\nproperty float x\nproperty float y\nproperty float z\n"
                    "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n"
                    "element face 9\n") != std::string::npos);
  const char* p = bytes.data() + body + header_end.size();
  const auto v = s.vertices.contiguous();
  const auto quant = [](float x) { return int(std::lround(255.0 * std::min(1.0, std::max(0.0, double(x))))); };
  for (int64_t i = 0; i < 9; ++i) {
    for (int k = 0; k < 3; ++k) {
      float xyz[3];
      std::memcpy(xyz, p, 12);
      const auto* rgba = reinterpret_cast<const unsigned char*>(p + 12);
      p += 16;
      for (int d = 0; d < 3; ++d) CHECK(xyz[d] == v[i][k][d].item<float>());
      for (int c = 0; c < 3; ++c) CHECK(int(rgba[c]) == quant(s.colors[i][c].item<float>()));
      CHECK(int(rgba[3]) == quant(s.opacities[i].item<float>()));
    }
  }
  // Spot checks by hand: clamping and rounding.
  const auto* first = reinterpret_cast<const unsigned char*>(bytes.data() + body + header_end.size() + 12);
  CHECK(int(first[0]) == 0);
  CHECK(int(first[1]) == 255);
  CHECK(int(first[2]) == 128);
  CHECK(int(first[3]) == 255);
  // The reader still takes the exact floats from the face properties.
  auto r = read_triangle_ply(path);
  CHECK(torch::equal(r.colors, s.colors));
  CHECK(torch::equal(r.opacities, s.opacities));
}

TEST_CASE("triangle ply: files without vertex colours (older layout) still read", "[export][ply]") {
  auto dir = flat::test::scratch_dir("triangle_ply_old_layout");
  auto s = flat::test::random_soup(5, torch::kFloat, 11);
  const auto v = s.vertices.contiguous();
  std::string out =
      "ply\nformat binary_little_endian 1.0\ncomment FLAT triangle soup (docs/formats.md)\n"
      "element vertex 15\nproperty float x\nproperty float y\nproperty float z\n"
      "element face 5\nproperty list uchar int vertex_indices\nproperty float red\nproperty float green\n"
      "property float blue\nproperty float opacity\nproperty float sigma\nend_header\n";
  out.append(reinterpret_cast<const char*>(v.data_ptr<float>()), 45 * sizeof(float));
  for (int i = 0; i < 5; ++i) {
    put<uint8_t>(out, 3);
    for (int k = 0; k < 3; ++k) put<int32_t>(out, 3 * i + k);
    for (int c = 0; c < 3; ++c) put<float>(out, s.colors[i][c].item<float>());
    put<float>(out, s.opacities[i].item<float>());
    put<float>(out, s.sigmas[i].item<float>());
  }
  const auto path = (dir / "old.ply").string();
  std::ofstream(path, std::ios::binary) << out;
  auto r = read_triangle_ply(path);
  CHECK(torch::equal(r.vertices, s.vertices));
  CHECK(torch::equal(r.colors, s.colors));
  CHECK(torch::equal(r.opacities, s.opacities));
  CHECK(torch::equal(r.sigmas, s.sigmas));

  // Other vertex properties are still refused, naming the element.
  std::string odd = out;
  const std::string xyz = "property float z\n";
  odd.insert(odd.find(xyz) + xyz.size(), "property uchar red\n");
  const auto odd_path = (dir / "odd.ply").string();
  std::ofstream(odd_path, std::ios::binary) << odd;
  REQUIRE_THROWS_WITH(read_triangle_ply(odd_path), FLAT_CONTAINS("odd.ply: element 'vertex'"));
}
