// Floater pruning (paper, Opaque Mesh Conversion, after stitching): pieces of
// the mesh with fewer than min_faces faces (connected through shared
// vertices, or through shared edges: edge_components.h) are removed; lone
// triangles among them. The grid conversion counts pieces through edges, as
// a face hanging on one vertex of a surface is no part of it.
#pragma once
#include <cstdint>

#include "flat/primitives/indexed_mesh.h"

namespace flat::mesh {

// (F,) int64 component label per face (0..C-1, in order of first face).
at::Tensor face_components(const primitives::IndexedMesh& mesh);

// The mesh without components of fewer than min_faces faces (vertices compacted).
primitives::IndexedMesh remove_small_components(const primitives::IndexedMesh& mesh, int64_t min_faces,
                                                int64_t* removed_faces = nullptr, bool through_edges = false);

}  // namespace flat::mesh
