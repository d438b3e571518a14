// The grid conversion's steps (issue #44): a view's depth as a grid mesh
// whose faces share edges, the fusion of views, floaters removed through
// edges, and the repair's normal-consistency term that keeps a plane planar.
#include <torch/torch.h>

#include "flat/mesh/depth_grid_mesh.h"
#include "flat/mesh/edge_components.h"
#include "flat/mesh/floaters.h"
#include "flat/mesh/mesh_smoothness.h"
#include "flat/mesh/mesh_statistics.h"
#include "flat/mesh/view_fusion.h"
#include "mesh/mesh_builders.h"
#include "test_support.h"

using namespace flat;

namespace {

const auto kIntrinsics = torch::tensor({0.9f, 1.2f, 0.5f, 0.5f});

primitives::IndexedMesh grid_of(const at::Tensor& depth) {
  const int64_t H = depth.size(0), W = depth.size(1);
  return mesh::depth_grid_mesh(depth, torch::full({3, H, W}, 0.5f), torch::ones({H, W}, torch::kBool), kIntrinsics,
                               torch::eye(4), {});
}

at::Tensor face_normals(const primitives::IndexedMesh& m) {
  const auto c = m.vertices.index_select(0, m.faces.reshape({-1})).reshape({-1, 3, 3});
  const auto n = at::cross(c.select(1, 1) - c.select(1, 0), c.select(1, 2) - c.select(1, 0), -1);
  return n / n.norm(2, -1, true);
}

}  // namespace

TEST_CASE("depth grid mesh: a flat depth map is one edge-connected sheet facing the camera", "[mesh]") {
  const auto m = grid_of(torch::full({6, 8}, 3.0f));
  CHECK(m.num_vertices() == 48);
  CHECK(m.num_faces() == 2 * 5 * 7);
  CHECK(mesh::edge_connected_pieces(m) == 1);
  const auto s = mesh::mesh_statistics(m);
  CHECK(s.non_manifold_edges_pct == 0.0);
  CHECK(s.boundary_edges_pct == Approx(100.0 * 2 * (5 + 7) / s.edges));  // only the rim is open
  // On the plane z = 3, unprojected through the pixel centres; normals point back at the camera (-z).
  CHECK((m.vertices.select(1, 2) - 3).abs().max().item<double>() < 1e-6);
  CHECK(face_normals(m).select(1, 2).max().item<double>() < -0.999);
  // The pixel (0,0) centre: x = (0.5 - cx) / fx * z with fx = 0.9 * 8, cx = 4.
  CHECK(m.vertices.select(1, 0).min().item<double>() == Approx((0.5 - 4.0) / 7.2 * 3.0).epsilon(1e-5));
}

TEST_CASE("depth grid mesh: a depth step opens the sheet, a tilted plane does not", "[mesh]") {
  auto step = torch::full({6, 8}, 3.0f);
  step.narrow(1, 4, 4).fill_(12.0f);  // a wall far behind: a discontinuity between columns 3 and 4
  const auto m = grid_of(step);
  CHECK(mesh::edge_connected_pieces(m) == 2);
  CHECK(m.num_faces() == 2 * 5 * 6);  // the column of quads across the step is gone
  // A floor seen obliquely: depth rising steadily down the image stays one sheet.
  const auto rows = torch::arange(6, torch::kFloat).unsqueeze(1).expand({6, 8});
  CHECK(mesh::edge_connected_pieces(grid_of(2.0f + 0.5f * rows)) == 1);
  CHECK(grid_of(2.0f + 0.5f * rows).num_faces() == 70);
}

TEST_CASE("depth grid mesh: invalid pixels leave holes, skipped faces are not made", "[mesh]") {
  const auto depth = torch::full({6, 8}, 3.0f);
  auto valid = torch::ones({6, 8}, torch::kBool);
  valid[2][3] = false;
  const auto holed = mesh::depth_grid_mesh(depth, torch::full({3, 6, 8}, 0.5f), valid, kIntrinsics, torch::eye(4), {});
  CHECK(holed.num_faces() == 70 - 6 + 2);  // the 4 quads around the pixel lose 6 faces; 2 corners keep a triangle
  auto skip = torch::zeros({6, 8}, torch::kBool);
  skip.narrow(1, 0, 4).fill_(true);  // columns 0..3 held by another view
  const auto rest = mesh::depth_grid_mesh(depth, torch::full({3, 6, 8}, 0.5f), torch::ones({6, 8}, torch::kBool),
                                          kIntrinsics, torch::eye(4), {}, skip);
  CHECK(rest.num_faces() == 2 * 5 * 4);  // columns 3..7's quads: the seam quads (3,4) kept, they overlap the rest
  CHECK(mesh::edge_connected_pieces(rest) == 1);
}

TEST_CASE("view fusion: the middle view first, then outwards", "[mesh]") {
  CHECK(mesh::fusion_order(1) == std::vector<int64_t>{0});
  CHECK(mesh::fusion_order(5) == std::vector<int64_t>{2, 3, 1, 4, 0});
  CHECK(mesh::fusion_order(4) == std::vector<int64_t>{2, 3, 1, 0});
}

TEST_CASE("floaters: a face hanging on one vertex is removed when pieces are counted through edges", "[mesh]") {
  // A 2x2 quad sheet (8 faces) and a triangle touching it at the corner vertex 0 only.
  auto sheet = grid_of(torch::full({3, 3}, 3.0f));
  REQUIRE(sheet.num_faces() == 8);
  const auto v0 = sheet.vertices[0];
  auto m = sheet;
  m.vertices = torch::cat({sheet.vertices, (v0 + torch::tensor({-0.3f, 0.f, 0.f})).unsqueeze(0),
                           (v0 + torch::tensor({0.f, -0.3f, 0.f})).unsqueeze(0)});
  m.colors = torch::full({m.num_vertices(), 3}, 0.5f);
  m.faces = torch::cat({sheet.faces, torch::tensor(std::vector<int64_t>{0, 9, 10}).reshape({1, 3})});
  int64_t removed = -1;
  const auto by_vertices = mesh::remove_small_components(m, 3, &removed);
  CHECK(removed == 0);  // through the shared vertex it is part of the sheet
  CHECK(by_vertices.num_faces() == 9);
  const auto by_edges = mesh::remove_small_components(m, 3, &removed, true);
  CHECK(removed == 1);
  CHECK(by_edges.num_faces() == 8);
  CHECK(by_edges.num_vertices() == 9);
}

TEST_CASE("normal consistency: zero on a plane, and descending it flattens a bump", "[mesh]") {
  auto plane = grid_of(torch::full({5, 5}, 3.0f));
  const auto pairs = mesh::edge_adjacent_face_pairs(plane.faces);
  // 4x4 quads: 32 faces, 3 * 32 = 96 face sides, 16 on the rim, so (96 - 16) / 2 = 40 interior edges.
  CHECK(pairs.size(0) == 40);
  auto v = plane.vertices.clone().requires_grad_(true);
  auto loss = mesh::normal_consistency(v, plane.faces, pairs);
  CHECK(loss.item<double>() < 1e-7);
  loss.backward();
  CHECK(v.grad().abs().max().item<double>() < 1e-5);  // a plane is a minimum: nothing moves it
  // A bump: the centre vertex (2,2) pushed 0.3 m towards the camera.
  auto bumped = plane.vertices.clone();
  bumped[12][2] = 2.7f;
  auto x = bumped.clone().requires_grad_(true);
  const double before = mesh::normal_consistency(x, plane.faces, pairs).item<double>();
  CHECK(before > 1e-3);
  for (int i = 0; i < 200; ++i) {
    auto l = mesh::normal_consistency(x, plane.faces, pairs);
    l.backward();
    {
      torch::NoGradGuard g;
      x -= 0.5 * x.grad();
      x.grad().zero_();
    }
  }
  const double after = mesh::normal_consistency(x, plane.faces, pairs).item<double>();
  INFO("normal consistency " << before << " -> " << after);
  CHECK(after < 0.1 * before);
  // Flat again: every vertex within 5 cm of one plane z = const.
  const auto z = x.detach().select(1, 2);
  CHECK((z.max() - z.min()).item<double>() < 0.05);
}
