// Triangle soup PLY: round trip, and clear errors on malformed files.
#include <fstream>

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/export/triangle_ply.h"
#include "render_scenes.h"
#include "test_support.h"

using flat::exporter::read_triangle_ply;
using flat::exporter::write_triangle_ply;

TEST_CASE("triangle ply: write then read gives the same soup", "[render][ply]") {
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

TEST_CASE("triangle ply: malformed files are reported with file and element", "[render][ply]") {
  auto dir = flat::test::scratch_dir("triangle_ply_errors");
  const auto missing = (dir / "nope.ply").string();
  REQUIRE_THROWS_WITH(read_triangle_ply(missing), FLAT_CONTAINS("nope.ply"));
  auto s = flat::test::random_soup(3, torch::kFloat, 4);
  const auto good = (dir / "good.ply").string();
  write_triangle_ply(good, {s.vertices, s.colors, s.opacities, s.sigmas});
  std::ifstream in(good, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto truncated = (dir / "truncated.ply").string();
  std::ofstream(truncated, std::ios::binary) << bytes.substr(0, bytes.size() - 10);
  REQUIRE_THROWS_WITH(read_triangle_ply(truncated), FLAT_CONTAINS("truncated.ply: element 'face'"));
  const auto ascii = (dir / "ascii.ply").string();
  std::ofstream(ascii) << "ply\nformat ascii 1.0\nelement vertex 0\nend_header\n";
  REQUIRE_THROWS_WITH(read_triangle_ply(ascii), FLAT_CONTAINS("binary_little_endian"));
  REQUIRE_THROWS_WITH(write_triangle_ply((dir / "x.ply").string(), {s.vertices.view({3, 9}), s.colors, s.opacities, s.sigmas}),
                      FLAT_CONTAINS("vertices"));
}
