#include "flat/mesh/mesh_statistics.h"

#include <algorithm>
#include <array>
#include <numeric>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "flat/mesh/edge_components.h"
#include "union_find.h"

namespace flat::mesh {

namespace {

struct Edge {
  int64_t a, b, face;  // a < b
  bool operator<(const Edge& o) const { return a != o.a ? a < o.a : (b != o.b ? b < o.b : face < o.face); }
};

double pct(int64_t part, int64_t whole) { return whole > 0 ? 100.0 * double(part) / double(whole) : 0.0; }

// Faces with a repeated index, or (almost) no area: area squared at most
// min_area2.
int64_t count_degenerate(const int64_t* f, const double* v, int64_t faces, double min_area2) {
  int64_t degenerate = 0;
  for (int64_t i = 0; i < faces; ++i) {
    const int64_t* t = f + 3 * i;
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) {
      ++degenerate;
      continue;
    }
    double e1[3], e2[3];
    for (int d = 0; d < 3; ++d) {
      e1[d] = v[3 * t[1] + d] - v[3 * t[0] + d];
      e2[d] = v[3 * t[2] + d] - v[3 * t[0] + d];
    }
    const double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2],
                 cz = e1[0] * e2[1] - e1[1] * e2[0];
    if (0.25 * (cx * cx + cy * cy + cz * cz) <= min_area2) ++degenerate;
  }
  return degenerate;
}

// Edges, sorted so that the faces of one edge are adjacent: their count, the
// non-manifold and boundary shares, and the mean number of faces a face
// shares an edge with.
void add_edge_statistics(const int64_t* f, MeshStatistics& s) {
  std::vector<Edge> edges;
  edges.reserve(size_t(3 * s.faces));
  for (int64_t i = 0; i < s.faces; ++i)
    for (int k = 0; k < 3; ++k) {
      const int64_t a = f[3 * i + k], b = f[3 * i + (k + 1) % 3];
      if (a != b) edges.push_back({std::min(a, b), std::max(a, b), i});
    }
  std::sort(edges.begin(), edges.end());
  std::vector<std::vector<int64_t>> neighbours(size_t(s.faces));
  int64_t non_manifold = 0, boundary = 0;
  for (size_t i = 0; i < edges.size();) {
    size_t j = i;
    while (j < edges.size() && edges[j].a == edges[i].a && edges[j].b == edges[i].b) ++j;
    // Faces of this edge, each counted once (a face can hold an edge twice only if degenerate).
    std::vector<int64_t> on_edge;
    for (size_t k = i; k < j; ++k)
      if (on_edge.empty() || on_edge.back() != edges[k].face) on_edge.push_back(edges[k].face);
    ++s.edges;
    if (on_edge.size() > 2) ++non_manifold;
    if (on_edge.size() == 1) ++boundary;
    for (int64_t a : on_edge)
      for (int64_t b : on_edge)
        if (a != b) neighbours[size_t(a)].push_back(b);
    i = j;
  }
  double total_neighbours = 0;
  for (auto& n : neighbours) {
    std::sort(n.begin(), n.end());
    total_neighbours += double(std::unique(n.begin(), n.end()) - n.begin());
  }
  s.mean_face_neighbours = total_neighbours / double(s.faces);
  s.non_manifold_edges_pct = pct(non_manifold, s.edges);
  s.boundary_edges_pct = pct(boundary, s.edges);
}

// Components and isolated faces through shared vertices.
void add_vertex_connectivity(const int64_t* f, MeshStatistics& s) {
  std::vector<int64_t> faces_of_vertex(size_t(s.vertices), 0);
  for (int64_t i = 0; i < 3 * s.faces; ++i) ++faces_of_vertex[size_t(f[i])];
  int64_t isolated = 0;
  UnionFind uf(s.faces);
  std::vector<int64_t> first_face(size_t(s.vertices), -1);
  for (int64_t i = 0; i < s.faces; ++i) {
    bool alone = true;
    for (int k = 0; k < 3; ++k) {
      const int64_t vi = f[3 * i + k];
      // A vertex repeated within one face counts that face more than once.
      int64_t own = 0;
      for (int q = 0; q < 3; ++q) own += f[3 * i + q] == vi;
      if (faces_of_vertex[size_t(vi)] > own) alone = false;
      if (first_face[size_t(vi)] < 0) first_face[size_t(vi)] = i;
      else uf.unite(first_face[size_t(vi)], i);
    }
    if (alone) ++isolated;
  }
  s.isolated_faces_pct = pct(isolated, s.faces);
  s.connected_components = uf.count();
}

}  // namespace

MeshStatistics mesh_statistics(const primitives::IndexedMesh& mesh, double area_eps) {
  primitives::check_mesh(mesh, "mesh statistics");
  MeshStatistics s;
  s.vertices = mesh.num_vertices();
  s.faces = mesh.num_faces();
  if (s.faces == 0) return s;
  const auto faces = mesh.faces.to(at::kCPU).contiguous();
  const auto verts = mesh.vertices.to(at::kCPU, at::kDouble).contiguous();
  const int64_t* f = faces.data_ptr<int64_t>();

  const auto extent = (verts.amax(0) - verts.amin(0)).norm().item<double>();
  const double min_area2 = std::pow(area_eps * extent * extent, 2);
  s.degenerate_faces_pct = pct(count_degenerate(f, verts.data_ptr<double>(), s.faces, min_area2), s.faces);
  add_edge_statistics(f, s);
  add_vertex_connectivity(f, s);
  s.edge_connected_pieces = edge_connected_pieces(mesh);
  return s;
}

nlohmann::json to_json(const MeshStatistics& s) {
  return {{"vertices", s.vertices},
          {"faces", s.faces},
          {"edges", s.edges},
          {"degenerate_faces_pct", s.degenerate_faces_pct},
          {"isolated_faces_pct", s.isolated_faces_pct},
          {"mean_face_neighbours", s.mean_face_neighbours},
          {"non_manifold_edges_pct", s.non_manifold_edges_pct},
          {"boundary_edges_pct", s.boundary_edges_pct},
          {"connected_components", s.connected_components},
          {"edge_connected_pieces", s.edge_connected_pieces}};
}

std::string format_statistics(const MeshStatistics& s) {
  return fmt::format(
      "{} vertices, {} faces, {} edges, {} connected components (through shared vertices), {} edge-connected "
      "pieces\n"
      "degenerate faces {:.2f}%, isolated triangles {:.2f}%, mean triangle neighbours {:.2f}, "
      "non-manifold edges {:.2f}%, boundary edges {:.2f}%",
      s.vertices, s.faces, s.edges, s.connected_components, s.edge_connected_pieces, s.degenerate_faces_pct, s.isolated_faces_pct,
      s.mean_face_neighbours, s.non_manifold_edges_pct, s.boundary_edges_pct);
}

}  // namespace flat::mesh
