// mesh_statistics on meshes whose answers are known by hand.
#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include "flat/mesh/mesh_statistics.h"
#include "mesh/mesh_builders.h"
#include "test_support.h"

using flat::mesh::mesh_statistics;

TEST_CASE("mesh statistics: a closed cube is one manifold piece with 3 neighbours per face", "[mesh]") {
  const auto s = mesh_statistics(flat::test::cube());
  CHECK(s.vertices == 8);
  CHECK(s.faces == 12);
  CHECK(s.edges == 18);
  CHECK(s.mean_face_neighbours == Approx(3.0));
  CHECK(s.non_manifold_edges_pct == 0.0);
  CHECK(s.boundary_edges_pct == 0.0);
  CHECK(s.degenerate_faces_pct == 0.0);
  CHECK(s.isolated_faces_pct == 0.0);
  CHECK(s.connected_components == 1);
}

TEST_CASE("mesh statistics: a strip has open edges and 1.5 neighbours per face", "[mesh]") {
  const auto s = mesh_statistics(flat::test::strip());
  CHECK(s.faces == 4);
  CHECK(s.edges == 9);
  CHECK(s.mean_face_neighbours == Approx(1.5));  // ends 1, middle 2
  CHECK(s.boundary_edges_pct == Approx(100.0 * 6 / 9));
  CHECK(s.non_manifold_edges_pct == 0.0);
  CHECK(s.connected_components == 1);
}

TEST_CASE("mesh statistics: three faces on one edge make it non-manifold", "[mesh]") {
  const auto s = mesh_statistics(flat::test::three_pages());
  CHECK(s.edges == 7);
  CHECK(s.non_manifold_edges_pct == Approx(100.0 / 7));
  CHECK(s.mean_face_neighbours == Approx(2.0));
  CHECK(s.connected_components == 1);
}

TEST_CASE("mesh statistics: degenerate faces, isolated triangles and separate pieces are counted", "[mesh]") {
  // The cube, a lone triangle far away, a face with a repeated vertex, and a
  // zero-area face (collinear vertices), the last two sharing vertices with the cube.
  auto m = flat::test::cube();
  m.vertices = torch::cat({m.vertices, torch::tensor(std::vector<float>{5, 5, 5, 6, 5, 5, 5, 6, 5, 2, 0, 0}).reshape({4, 3})});
  m.colors = torch::full({12, 3}, 0.5f);
  m.faces = torch::cat({m.faces, torch::tensor(std::vector<int64_t>{8, 9, 10, 0, 0, 1, 0, 1, 11}).reshape({3, 3})});
  const auto s = mesh_statistics(m);
  CHECK(s.faces == 15);
  CHECK(s.degenerate_faces_pct == Approx(100.0 * 2 / 15));
  CHECK(s.isolated_faces_pct == Approx(100.0 / 15));  // only the lone triangle shares no vertex
  CHECK(s.connected_components == 2);
  // to_json carries the same figures.
  const auto j = flat::mesh::to_json(s);
  CHECK(j["faces"].get<int64_t>() == 15);
  CHECK(j["connected_components"].get<int64_t>() == 2);
}

TEST_CASE("mesh statistics: out-of-range face indices are an error naming them", "[mesh]") {
  auto m = flat::test::strip();
  m.faces[0][0] = 17;
  REQUIRE_THROWS_WITH(mesh_statistics(m), FLAT_CONTAINS("face index out of range"));
}

TEST_CASE("mesh statistics: edge-connected pieces join faces through shared edges only", "[mesh]") {
  // Two triangles sharing the edge (1,2): one piece either way.
  const auto shared_edge = flat::test::make_mesh({0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0}, {0, 1, 2, 1, 3, 2});
  const auto a = mesh_statistics(shared_edge);
  CHECK(a.connected_components == 1);
  CHECK(a.edge_connected_pieces == 1);
  // Two triangles sharing only vertex 0 (a bow-tie): welded, not stitched.
  const auto shared_vertex =
      flat::test::make_mesh({0, 0, 0, 1, 0, 0, 1, 1, 0, -1, 0, 0, -1, -1, 0}, {0, 1, 2, 0, 3, 4});
  const auto b = mesh_statistics(shared_vertex);
  CHECK(b.connected_components == 1);
  CHECK(b.edge_connected_pieces == 2);
  CHECK(flat::mesh::to_json(b)["edge_connected_pieces"].get<int64_t>() == 2);
  // A closed cube and a strip are one piece; the strip's faces are chained by edges.
  CHECK(mesh_statistics(flat::test::cube()).edge_connected_pieces == 1);
  CHECK(mesh_statistics(flat::test::strip()).edge_connected_pieces == 1);
  // A fan of three faces around vertex 0 with one gap: faces 0-1 share an
  // edge, face 2 touches them at vertex 0 only.
  const auto fan = flat::test::make_mesh({0, 0, 0, 1, 0, 0, 0, 1, 0, -1, 0, 0, 0, -1, 0}, {0, 1, 2, 0, 2, 3, 0, 4, 1 + 0});
  CHECK(mesh_statistics(fan).edge_connected_pieces == 1);  // face 2 = (0,4,1) shares edge (0,1) with face 0
  const auto open_fan = flat::test::make_mesh({0, 0, 0, 1, 0, 0, 0, 1, 0, -1, 0, 0, 0, -1, 0, 0.5f, -1, 0},
                                              {0, 1, 2, 0, 2, 3, 0, 4, 5});
  CHECK(mesh_statistics(open_fan).edge_connected_pieces == 2);
  CHECK(mesh_statistics(open_fan).connected_components == 1);
}
