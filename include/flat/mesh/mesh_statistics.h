// The mesh figures of the paper's appendix "Mesh Conversion Analysis":
// degenerate faces, isolated triangles, mean triangle neighbours,
// non-manifold edges, connected components (through shared vertices, and
// through shared edges: welded vertices alone do not make a surface).
#pragma once
#include <cstdint>
#include <string>

#include <nlohmann/json_fwd.hpp>

#include "flat/primitives/indexed_mesh.h"

namespace flat::mesh {

struct MeshStatistics {
  int64_t vertices = 0, faces = 0;
  int64_t edges = 0;                 // distinct undirected edges
  double degenerate_faces_pct = 0;   // faces with a repeated vertex or an area below area_eps * extent^2
  double isolated_faces_pct = 0;     // faces that share no vertex with any other face
  double mean_face_neighbours = 0;   // faces sharing an edge with a face, averaged over faces (3 on a closed manifold)
  double non_manifold_edges_pct = 0; // edges of more than two faces, over all edges
  double boundary_edges_pct = 0;     // edges of exactly one face, over all edges
  int64_t connected_components = 0;  // faces joined through shared vertices
  int64_t edge_connected_pieces = 0; // faces joined through shared edges (edge_components.h): the stitched surface
};

// area_eps: relative to the squared bounding-box diagonal.
MeshStatistics mesh_statistics(const primitives::IndexedMesh& mesh, double area_eps = 1e-12);

nlohmann::json to_json(const MeshStatistics& s);
std::string format_statistics(const MeshStatistics& s);  // a few lines for the terminal

}  // namespace flat::mesh
