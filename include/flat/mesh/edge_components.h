// Edge-connected pieces: faces joined only through shared edges (two shared
// vertices), not through a lone shared vertex. Welding vertices alone can
// make a soup "one component" through shared vertices while every triangle
// still hangs on its own edges (issue #44: 1,971 faces, 1 vertex-connected
// piece per few faces, 1,025 edge-connected pieces); this is the count that
// says whether the surface is stitched.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

#include "flat/primitives/indexed_mesh.h"

namespace flat::mesh {

// (F,) int64 piece label per face (0..P-1, in order of first face): union-find
// over faces that share an undirected edge. Degenerate edges (a == b) join nothing.
at::Tensor edge_connected_labels(const primitives::IndexedMesh& mesh);

// Number of edge-connected pieces (0 for a mesh without faces).
int64_t edge_connected_pieces(const primitives::IndexedMesh& mesh);

}  // namespace flat::mesh
