// Stitching merges exactly the mutually nearest boundary vertices (within the
// distance), floaters go, and the open border is densified where asked.
#include <cmath>

#include <torch/torch.h>

#include "flat/mesh/boundary_densify.h"
#include "flat/mesh/floaters.h"
#include "flat/mesh/mesh_statistics.h"
#include "flat/mesh/vertex_stitch.h"
#include "mesh/mesh_builders.h"
#include "test_support.h"

using namespace flat;

namespace {

// Three separate triangles on a line. A's corner a1 = (1,0,0), B's corner
// b0 = (1.05,0,0), C's corner c0 = (1.2,0,0): a1 and b0 are each other's
// nearest; c0's nearest is b0, whose nearest is a1, so c0 stays open.
primitives::IndexedMesh three_triangles() {
  return test::make_mesh({0, 0, 0, 1, 0, 0, 0, 1, 0,            // A: 0 1 2
                          1.05f, 0, 0, 2, 0, 0, 1.5f, 1, 0,     // B: 3 4 5
                          1.2f, 0, 0, 1.2f, -1, 0, 3, -1, 0},   // C: 6 7 8
                         {0, 1, 2, 3, 4, 5, 6, 7, 8});
}

}  // namespace

TEST_CASE("stitching: nearest partners skip face mates and respect the distance", "[mesh]") {
  const auto m = three_triangles();
  const auto all = torch::ones({9}, torch::kBool);
  const auto p = mesh::nearest_partners(m, all, torch::full({9}, 0.3f));
  CHECK(p[1].item<int64_t>() == 3);   // a1 -> b0
  CHECK(p[3].item<int64_t>() == 1);   // b0 -> a1
  CHECK(p[6].item<int64_t>() == 3);   // c0 -> b0 (0.15), not mutual
  CHECK(p[0].item<int64_t>() == -1);  // (0,0,0): nearest non-mate is b0 at 1.05 > 0.3
  // A vertex's own triangle never offers its partner, however close.
  auto tiny = test::make_mesh({0, 0, 0, 1e-4f, 0, 0, 0, 1e-4f, 0}, {0, 1, 2});
  CHECK((mesh::nearest_partners(tiny, torch::ones({3}, torch::kBool), torch::ones({3})) == -1).all().item<bool>());
}

TEST_CASE("stitching: a pair must be within both vertices' radius", "[mesh]") {
  // a1 and b0 are 0.05 apart: a radius of 0.04 on either side keeps them apart.
  auto radius = torch::full({9}, 0.3f);
  radius[3] = 0.04f;
  const auto p = mesh::nearest_partners(three_triangles(), torch::ones({9}, torch::kBool), radius);
  CHECK(p[3].item<int64_t>() == -1);
  CHECK(p[1].item<int64_t>() == 6);  // a1 falls back to c0 (0.2 away, within both radii)
  // Local scales: the mean edge length of the faces at each vertex.
  const auto s = mesh::vertex_scales(three_triangles());
  CHECK(s[0].item<double>() == Approx((2 + std::sqrt(2.0)) / 3).epsilon(1e-5));
}

TEST_CASE("stitching merges exactly the mutually nearest pairs, at their midpoint", "[mesh]") {
  mesh::StitchReport r;
  const auto out = mesh::stitch_boundary_vertices(three_triangles(), {0.3, 0.0, 1}, &r);
  CHECK(r.merged_pairs == 1);
  CHECK(r.collapsed_faces == 0);
  REQUIRE(out.num_vertices() == 8);
  REQUIRE(out.num_faces() == 3);
  // A and B now share one vertex at (1.025, 0, 0); C is still apart.
  const auto f = out.faces;
  const int64_t shared = f[0][1].item<int64_t>();
  CHECK(f[1][0].item<int64_t>() == shared);
  CHECK(torch::allclose(out.vertices[shared], torch::tensor({1.025f, 0.f, 0.f})));
  CHECK(mesh::mesh_statistics(out).connected_components == 2);
  // A second round pairs c0 with the merged vertex (now mutually nearest).
  const auto two = mesh::stitch_boundary_vertices(three_triangles(), {0.3, 0.0, 2}, &r);
  CHECK(r.merged_pairs == 2);
  CHECK(mesh::mesh_statistics(two).connected_components == 1);
  // Nothing within the distance: nothing changes.
  const auto none = mesh::stitch_boundary_vertices(three_triangles(), {0.01, 0.0, 3}, &r);
  CHECK(r.merged_pairs == 0);
  CHECK(none.num_vertices() == 9);
}

TEST_CASE("stitching leaves colour seams open", "[mesh]") {
  // A and C red, B blue: a1's nearest (b0) is the wrong colour, so a1 pairs
  // with c0 (0.2 away) and b0 stays an open seam.
  auto m = three_triangles();
  m.colors.copy_(torch::tensor({1.f, 0.f, 0.f}).expand({9, 3}));
  m.colors.slice(0, 3, 6).copy_(torch::tensor({0.f, 0.f, 1.f}).expand({3, 3}));
  const auto p = mesh::nearest_partners(m, torch::ones({9}, torch::kBool), torch::full({9}, 0.3f), 0.15);
  CHECK(p[1].item<int64_t>() == 6);
  CHECK(p[6].item<int64_t>() == 1);
  CHECK(p[3].item<int64_t>() == -1);
  mesh::StitchReport r;
  const auto out = mesh::stitch_boundary_vertices(m, {0.3, 0.15, 3}, &r);
  CHECK(r.merged_pairs == 1);
  CHECK(out.num_vertices() == 8);
  // Without the colour limit, a1 and b0 merge first.
  CHECK(mesh::nearest_partners(m, torch::ones({9}, torch::kBool), torch::full({9}, 0.3f), 0.0)[1].item<int64_t>() == 3);
}

TEST_CASE("stitching: two copies of one triangle merge into one face", "[mesh]") {
  auto m = test::make_mesh({0, 0, 0, 1, 0, 0, 0, 1, 0, 0.01f, 0, 0, 1.01f, 0, 0, 0.01f, 1, 0}, {0, 1, 2, 3, 4, 5});
  mesh::StitchReport r;
  const auto out = mesh::stitch_boundary_vertices(m, {0.1, 0.0, 1}, &r);
  CHECK(r.merged_pairs == 3);
  CHECK(r.collapsed_faces == 1);
  CHECK(out.num_faces() == 1);
  CHECK(out.num_vertices() == 3);
}

TEST_CASE("stitching only considers boundary vertices", "[mesh]") {
  // The closed cube has no boundary vertex: a lone triangle touching a corner is not merged into it.
  auto m = test::cube();
  m.vertices = torch::cat({m.vertices, torch::tensor(std::vector<float>{-0.01f, 0, 0, -1, 0, 0, -1, -1, 0}).reshape({3, 3})});
  m.colors = torch::full({11, 3}, 0.5f);
  m.faces = torch::cat({m.faces, torch::tensor(std::vector<int64_t>{8, 9, 10}).reshape({1, 3})});
  CHECK(mesh::boundary_vertices(m).sum().item<int64_t>() == 3);
  mesh::StitchReport r;
  mesh::stitch_boundary_vertices(m, {0.5, 0.0, 3}, &r);
  CHECK(r.merged_pairs == 0);
}

TEST_CASE("floaters: pieces below the size are removed, vertices compacted", "[mesh]") {
  auto m = test::cube();
  m.vertices = torch::cat({m.vertices, torch::tensor(std::vector<float>{5, 5, 5, 6, 5, 5, 5, 6, 5}).reshape({3, 3})});
  m.colors = torch::full({11, 3}, 0.5f);
  m.faces = torch::cat({m.faces, torch::tensor(std::vector<int64_t>{8, 9, 10}).reshape({1, 3})});
  const auto labels = mesh::face_components(m);
  CHECK(labels.max().item<int64_t>() == 1);
  int64_t removed = 0;
  const auto out = mesh::remove_small_components(m, 2, &removed);
  CHECK(removed == 1);
  CHECK(out.num_faces() == 12);
  CHECK(out.num_vertices() == 8);
  CHECK(mesh::remove_small_components(m, 13, &removed).num_faces() == 0);
  CHECK(removed == 13);
}

TEST_CASE("densification splits open faces with a long open edge 1 -> 4, sharing midpoints", "[mesh]") {
  // Strip: every face has an open edge of length 1 (the diagonals are shared).
  int64_t split = 0;
  const auto out = mesh::densify_boundary(test::strip(), 0.5, &split);
  CHECK(split == 4);
  CHECK(out.num_faces() == 16);
  // 6 corners + one midpoint per distinct edge of the strip (9): shared, not doubled.
  CHECK(out.num_vertices() == 15);
  CHECK(mesh::mesh_statistics(out).connected_components == 1);
  // Total area is unchanged, and no face is degenerate.
  const auto area = [](const primitives::IndexedMesh& m) {
    const auto v = m.vertices.index_select(0, m.faces.reshape({-1})).reshape({-1, 3, 3});
    return (0.5 * torch::cross(v.select(1, 1) - v.select(1, 0), v.select(1, 2) - v.select(1, 0), 1).norm(2, 1))
        .sum()
        .item<double>();
  };
  CHECK(area(out) == Approx(area(test::strip())));
  CHECK(mesh::mesh_statistics(out).degenerate_faces_pct == 0.0);
  // Closed surfaces have no open edge: nothing to split.
  mesh::densify_boundary(test::cube(), 0.1, &split);
  CHECK(split == 0);
  // Short open edges are left alone.
  mesh::densify_boundary(test::strip(), 1.5, &split);
  CHECK(split == 0);
}
