// Local densification near boundaries (paper, Opaque Mesh Conversion): faces
// on the open border of the mesh (a boundary edge, one that no other face
// uses) whose longest boundary edge exceeds min_edge are split 1 -> 4 at
// their edge midpoints, so that the stitching finds vertices along long open
// edges, not only at their corners. Midpoints are shared between split
// neighbours; a midpoint takes the mean colour of its edge's ends.
#pragma once
#include <cstdint>

#include "flat/primitives/indexed_mesh.h"

namespace flat::mesh {

primitives::IndexedMesh densify_boundary(const primitives::IndexedMesh& mesh, double min_edge,
                                         int64_t* split_faces = nullptr);

}  // namespace flat::mesh
