// The opaque conversion of a small soup: a connected, opaque mesh that still
// renders the targets (far better than a flat grey), with no lone triangles.
#include <torch/torch.h>

#include "flat/mesh/mesh_statistics.h"
#include "flat/mesh/opaque_conversion.h"
#include "flat/render/rasterize.h"
#include "test_support.h"

using namespace flat;

namespace {

// A textured wall at z = 3 seen by 3 cameras at 24x32, and a soup of small
// triangles that tiles it (as a feedforward soup does: one per 2x2 block).
struct Wall {
  mesh::ViewTargets targets;
  primitives::TriangleSoup soup;
};

// opacity, sigma: the soup's (a weak feedforward soup: 0.6, 0.5; a refined one is more opaque and sharper).
// gx, gy: cells of 0.25 m (~2.4 pixels), the wall centred on the view (10 x 8: inside the
// views; 16 x 12: beyond them, as a room's wall fills its frames).
// checker: cells per square of the colour pattern.
Wall wall(float opacity = 0.6f, float sigma = 0.5f, int64_t gx = 10, int64_t gy = 8, int64_t checker = 2) {
  std::vector<float> v, c;
  for (int64_t j = 0; j < gy; ++j)
    for (int64_t i = 0; i < gx; ++i) {
      const float x0 = -0.125f * float(gx) + 0.25f * float(i), y0 = -0.125f * float(gy) + 0.25f * float(j), e = 0.25f;
      const float col = ((i / checker + j / checker) % 2) ? 0.9f : 0.2f;
      for (int t = 0; t < 2; ++t) {
        const std::vector<float> tri = t == 0 ? std::vector<float>{x0, y0, 3, x0 + e, y0, 3, x0, y0 + e, 3}
                                              : std::vector<float>{x0 + e, y0, 3, x0 + e, y0 + e, 3, x0, y0 + e, 3};
        v.insert(v.end(), tri.begin(), tri.end());
        c.insert(c.end(), {col, 0.5f, 1.f - col});
      }
    }
  const int64_t n = int64_t(v.size() / 9);
  const auto vertices = torch::tensor(v).reshape({n, 3, 3});
  const auto colors = torch::tensor(c).reshape({n, 3});
  camera::Cameras cams;
  cams.intrinsics = torch::tensor({0.9f, 1.2f, 0.5f, 0.5f}).repeat({3, 1});
  cams.c2w = torch::eye(4).repeat({3, 1, 1});
  for (int64_t k = 0; k < 3; ++k) cams.c2w[k][0][3] = 0.1f * float(k - 1);
  render::RasterSettings sharp;
  sharp.eps = 0.0;
  const auto ones = torch::ones({n});
  const auto out = render::rasterize(vertices, colors, ones * 0.999, ones * 0.01, cams, 24, 32, sharp);
  // The soup to convert: the same triangles, jittered, semi-transparent and soft.
  auto gen = at::make_generator<at::CPUGeneratorImpl>(3);
  return {{out.rgb.detach(), {}, {}, cams},
          {vertices + 0.02 * at::randn({n, 3, 3}, gen), colors, ones * opacity, ones * sigma}};
}

double psnr(const primitives::TriangleSoup& s, const mesh::ViewTargets& t, const render::RasterSettings& raster) {
  const auto out = render::rasterize(s.vertices, s.colors, s.opacities, s.sigmas, t.cameras, 24, 32, raster);
  return -10 * std::log10((out.rgb.clamp(0, 1) - t.rgb).square().mean().item<double>());
}

// The wall's soup converted with `o` in a short run (20 repair steps, 3
// views a step): the mesh, the report and the mesh's statistics.
struct Converted {
  primitives::IndexedMesh mesh;
  mesh::ConversionReport report;
  mesh::MeshStatistics stats;
};
Converted convert_short(const Wall& w, mesh::OpaqueOptions o) {
  o.repair_steps = 20;
  o.views_per_step = 3;
  Converted c;
  c.mesh = mesh::convert_to_opaque_mesh(w.soup, w.targets, o, &c.report);
  c.stats = mesh::mesh_statistics(c.mesh);
  return c;
}

// The mesh, rendered opaque, shows the wall: its PSNR is far (6 dB) above
// the flat mean colour's.
void check_renders_the_wall(const primitives::IndexedMesh& m, const Wall& w, const mesh::OpaqueOptions& o) {
  const double mesh_psnr = psnr(mesh::opaque_render_soup(m, o), w.targets, mesh::opaque_raster(o.raster));
  const auto mean = w.targets.rgb.mean({0, 2, 3}, true);
  const double oracle = -10 * std::log10((w.targets.rgb - mean).square().mean().item<double>());
  INFO("mesh " << mesh_psnr << " dB, mean-colour oracle " << oracle << " dB");
  CHECK(mesh_psnr > oracle + 6.0);
}

}  // namespace

TEST_CASE("opaque conversion: a soup of a wall becomes a connected opaque mesh that renders the wall", "[mesh]") {
  const auto w = wall();
  mesh::OpaqueOptions o;
  o.conversion = "stitch";  // the paper's selection and vertex stitching
  o.selection_steps = 20;
  const auto [m, r, stats] = convert_short(w, o);
  INFO(mesh::format_statistics(stats));
  CHECK(m.num_faces() > 0);
  CHECK(r.stitched_pairs > 0);
  CHECK(stats.isolated_faces_pct == 0.0);  // floaters below 3 faces are gone
  CHECK(stats.mean_face_neighbours > 1.0);  // stitching joined the tiles
  CHECK(stats.connected_components < m.num_faces() / 3);
  // It still renders the wall: far above the flat mean colour.
  check_renders_the_wall(m, w, o);
  // Opaque: the render's alpha is ~1 wherever the mesh is.
  CHECK(r.stage_psnr.size() >= 4);
  // Each stage's wall time beside its PSNR (the log's trail), adding up to at most the whole.
  REQUIRE(r.stage_seconds.size() == r.stage_psnr.size());
  double stages = 0;
  for (double s : r.stage_seconds) {
    CHECK(s >= 0);
    stages += s;
  }
  CHECK(stages <= r.seconds + 1e-3);
}

TEST_CASE("opaque conversion (view grids): the wall becomes one flat, edge-connected sheet that renders it", "[mesh]") {
  // Squares of ~10 pixels: the grid samples every 2 pixels (the token grid), finer texture aliases.
  const auto w = wall(0.9f, 0.1f, 16, 12, 4);
  const mesh::OpaqueOptions o;  // conversion "grid", the default
  const auto [m, r, stats] = convert_short(w, o);
  INFO(mesh::format_statistics(stats));
  REQUIRE(m.num_faces() > 50);
  // Three views of one wall: the middle view's sheet, and strips from the side views.
  CHECK(stats.edge_connected_pieces <= m.num_faces() / 20);
  CHECK(stats.boundary_edges_pct < 30.0);
  CHECK(r.fused_faces < r.grid_faces);  // the side views added only what the middle one lacks
  // Flat: every vertex on the jittered soup's plane z = 3 (jitter 0.02 m), every face normal along z.
  CHECK((m.vertices.select(1, 2) - 3).abs().max().item<double>() < 0.1);
  const auto c = m.vertices.index_select(0, m.faces.reshape({-1})).reshape({-1, 3, 3});
  auto n = at::cross(c.select(1, 1) - c.select(1, 0), c.select(1, 2) - c.select(1, 0), -1);
  n = n / n.norm(2, -1, true);
  CHECK(n.select(1, 2).abs().min().item<double>() > 0.95);
  check_renders_the_wall(m, w, o);
}

TEST_CASE("opaque conversion refuses SH colours and inverted sigma schedules", "[mesh]") {
  const auto w = wall();
  mesh::OpaqueOptions o;
  auto sh = w.soup;
  sh.colors = torch::zeros({sh.vertices.size(0), 4, 3});
  REQUIRE_THROWS_WITH(mesh::convert_to_opaque_mesh(sh, w.targets, o), FLAT_CONTAINS("RGB colours"));
  o.sigma_end = 1.0;
  REQUIRE_THROWS_WITH(mesh::convert_to_opaque_mesh(w.soup, w.targets, o), FLAT_CONTAINS("sigma_end"));
}
