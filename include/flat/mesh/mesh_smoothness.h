// Normal consistency for the repair stage (issue #44): 1 - cos of the angle
// between the normals of faces that share an edge, averaged over those
// edges. The photometric term alone moves vertices along noisy gradients
// (sharp windows) and bends flat walls; this term is zero on any plane, so
// it flattens bumps without pulling a planar surface anywhere, and it leaves
// creases between pieces that share no edge alone.
#pragma once
#include <ATen/ATen.h>

namespace flat::mesh {

// (E,2) int64: pairs of faces (F,3) that share an undirected edge (each pair once).
at::Tensor edge_adjacent_face_pairs(const at::Tensor& faces);

// Mean of 1 - n_a . n_b over the pairs (E,2), unit face normals of vertices
// (V,3); differentiable w.r.t. vertices. 0 when there are no pairs.
at::Tensor normal_consistency(const at::Tensor& vertices, const at::Tensor& faces, const at::Tensor& pairs);

}  // namespace flat::mesh
