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

Wall wall() {
  const int64_t gx = 10, gy = 8;  // cells of 0.25 m, ~7 pixels
  std::vector<float> v, c;
  for (int64_t j = 0; j < gy; ++j)
    for (int64_t i = 0; i < gx; ++i) {
      const float x0 = -1.25f + 0.25f * float(i), y0 = -1.0f + 0.25f * float(j), e = 0.25f;
      const float col = ((i / 2 + j / 2) % 2) ? 0.9f : 0.2f;
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
          {vertices + 0.02 * at::randn({n, 3, 3}, gen), colors, ones * 0.6, ones * 0.5}};
}

double psnr(const primitives::TriangleSoup& s, const mesh::ViewTargets& t, const render::RasterSettings& raster) {
  const auto out = render::rasterize(s.vertices, s.colors, s.opacities, s.sigmas, t.cameras, 24, 32, raster);
  return -10 * std::log10((out.rgb.clamp(0, 1) - t.rgb).square().mean().item<double>());
}

}  // namespace

TEST_CASE("opaque conversion: a soup of a wall becomes a connected opaque mesh that renders the wall", "[mesh]") {
  const auto w = wall();
  mesh::OpaqueOptions o;
  o.selection_steps = 20;
  o.repair_steps = 20;
  o.views_per_step = 3;
  mesh::ConversionReport r;
  const auto m = mesh::convert_to_opaque_mesh(w.soup, w.targets, o, &r);
  const auto stats = mesh::mesh_statistics(m);
  INFO(mesh::format_statistics(stats));
  CHECK(m.num_faces() > 0);
  CHECK(r.stitched_pairs > 0);
  CHECK(stats.isolated_faces_pct == 0.0);  // floaters below 3 faces are gone
  CHECK(stats.mean_face_neighbours > 1.0);  // stitching joined the tiles
  CHECK(stats.connected_components < m.num_faces() / 3);
  // It still renders the wall: far above the flat mean colour.
  const double mesh_psnr = psnr(mesh::opaque_render_soup(m, o), w.targets, mesh::opaque_raster(o.raster));
  const auto mean = w.targets.rgb.mean({0, 2, 3}, true);
  const double oracle = -10 * std::log10((w.targets.rgb - mean).square().mean().item<double>());
  INFO("mesh " << mesh_psnr << " dB, mean-colour oracle " << oracle << " dB");
  CHECK(mesh_psnr > oracle + 6.0);
  // Opaque: the render's alpha is ~1 wherever the mesh is.
  CHECK(r.stage_psnr.size() >= 4);
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
