// Welding a view's grid onto the mesh of the views before it (issue #44):
// two views of one plane make one edge-connected sheet, not two sheets
// overlapping by a ring of faces.
#include <torch/torch.h>

#include "flat/mesh/depth_grid_mesh.h"
#include "flat/mesh/edge_components.h"
#include "flat/mesh/mesh_statistics.h"
#include "flat/mesh/opaque_conversion.h"
#include "flat/mesh/seam_weld.h"
#include "flat/mesh/view_fusion.h"
#include "test_support.h"

using namespace flat;

namespace {

const auto kIntrinsics = torch::tensor({0.9f, 1.2f, 0.5f, 0.5f});

primitives::IndexedMesh grid(const at::Tensor& depth, const at::Tensor& valid, const at::Tensor& skip = {}) {
  return mesh::depth_grid_mesh(depth, torch::full({3, depth.size(0), depth.size(1)}, 0.5f), valid, kIntrinsics,
                               torch::eye(4), {}, skip);
}

primitives::IndexedMesh appended(const primitives::IndexedMesh& a, const primitives::IndexedMesh& b) {
  return {torch::cat({a.vertices, b.vertices}), torch::cat({a.colors, b.colors}),
          torch::cat({a.faces, b.faces + a.num_vertices()})};
}

// An opaque, sharp soup tiling the plane z = 3 (cells of 0.1 m), x in [-3, 3], y in [-2, 2].
primitives::TriangleSoup plane_soup() {
  std::vector<float> v;
  for (int j = 0; j < 40; ++j)
    for (int i = 0; i < 60; ++i) {
      const float x = -3.0f + 0.1f * float(i), y = -2.0f + 0.1f * float(j), e = 0.1f;
      v.insert(v.end(), {x, y, 3, x + e, y, 3, x, y + e, 3, x + e, y, 3, x + e, y + e, 3, x, y + e, 3});
    }
  const int64_t n = int64_t(v.size() / 9);
  const auto ones = torch::ones({n});
  return {torch::tensor(v).reshape({n, 3, 3}), torch::full({n, 3}, 0.5f), ones * 0.999, ones * 0.01};
}

}  // namespace

TEST_CASE("seam weld: a view's half of a plane joins the other half through shared edges", "[mesh]") {
  const auto depth = torch::full({6, 8}, 3.0f);
  auto left = torch::zeros({6, 8}, torch::kBool);
  left.narrow(1, 0, 5).fill_(true);  // the first view's surface: columns 0..4
  const auto first = grid(depth, left);
  // The second view (here the same camera) holds columns 0..4 already; its seam quads (4,5) reach into them.
  const auto second = grid(depth, torch::ones({6, 8}, torch::kBool), left);
  REQUIRE(mesh::edge_connected_pieces(appended(first, second)) == 2);  // side by side, as the fusion did before
  mesh::SeamWeldReport r;
  const auto m = mesh::weld_view_seam(first, second, left, kIntrinsics, torch::eye(4), {}, &r);
  CHECK(r.welded_vertices == 6);  // column 4 of the second view is the first view's rim
  CHECK(r.dropped_faces == 0);
  CHECK(r.unwelded_vertices == 0);
  // Exactly the grid of the whole view: 48 vertices, 70 faces, one sheet open only at its rim.
  const auto whole = mesh::mesh_statistics(grid(depth, torch::ones({6, 8}, torch::kBool)));
  const auto s = mesh::mesh_statistics(m);
  CHECK(s.vertices == 48);
  CHECK(s.faces == 70);
  CHECK(s.edge_connected_pieces == 1);
  CHECK(s.non_manifold_edges_pct == 0.0);
  CHECK(s.boundary_edges_pct == Approx(whole.boundary_edges_pct));
  // The first view's vertices keep their indices.
  CHECK(torch::equal(m.vertices.narrow(0, 0, first.num_vertices()), first.vertices));
}

TEST_CASE("seam weld: a surface at another depth is not welded on", "[mesh]") {
  auto left = torch::zeros({6, 8}, torch::kBool);
  left.narrow(1, 0, 5).fill_(true);
  const auto first = grid(torch::full({6, 8}, 3.0f), left);
  const auto behind = grid(torch::full({6, 8}, 3.5f), torch::ones({6, 8}, torch::kBool), left);  // 17% deeper
  mesh::SeamWeldReport r;
  const auto m = mesh::weld_view_seam(first, behind, left, kIntrinsics, torch::eye(4), {}, &r);
  CHECK(r.welded_vertices == 0);
  CHECK(mesh::edge_connected_pieces(m) == 2);
  CHECK(m.num_faces() == first.num_faces() + behind.num_faces());
}

TEST_CASE("view fusion: two overlapping views of one plane make one edge-connected sheet", "[mesh]") {
  const auto soup = plane_soup();
  camera::Cameras cams;
  cams.intrinsics = kIntrinsics.repeat({2, 1});
  cams.c2w = torch::eye(4).repeat({2, 1, 1});
  cams.c2w[0][0][3] = -0.8f;  // each view sees ~3.3 m of the plane's width; 1.6 m apart, they overlap by half
  cams.c2w[1][0][3] = 0.8f;
  const mesh::ViewTargets targets{torch::zeros({2, 3, 24, 32}), {}, {}, cams};
  mesh::ViewFusionOptions o;
  o.mesh_raster = mesh::opaque_raster({});
  mesh::ViewFusionReport r;
  const auto welded = mesh::fuse_view_grids(soup, targets, {}, o, &r);
  const auto s = mesh::mesh_statistics(welded);
  INFO(mesh::format_statistics(s));
  CHECK(r.welded_vertices >= 12);  // the seam runs down the 13 rows of the 24-pixel-high grid
  CHECK(s.edge_connected_pieces == 1);
  CHECK(s.connected_components == 1);
  CHECK(s.non_manifold_edges_pct == 0.0);
  // Flat: every vertex on z = 3.
  CHECK((welded.vertices.select(1, 2) - 3).abs().max().item<double>() < 0.01);
  // Without the weld the second view's strip lies beside the first sheet: two pieces.
  o.weld = false;
  const auto apart = mesh::fuse_view_grids(soup, targets, {}, o);
  CHECK(mesh::mesh_statistics(apart).connected_components == 2);
}
