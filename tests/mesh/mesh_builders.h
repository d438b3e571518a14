// Hand-built meshes with known statistics, for the mesh module's tests.
#pragma once
#include <vector>

#include <torch/torch.h>

#include "flat/primitives/indexed_mesh.h"

namespace flat::test {

inline primitives::IndexedMesh make_mesh(const std::vector<float>& xyz, const std::vector<int64_t>& faces) {
  const int64_t v = int64_t(xyz.size() / 3), f = int64_t(faces.size() / 3);
  return {torch::tensor(xyz).reshape({v, 3}), torch::full({v, 3}, 0.5f), torch::tensor(faces).reshape({f, 3})};
}

// The unit cube: 8 vertices, 12 faces wound outwards, closed and manifold.
inline primitives::IndexedMesh cube() {
  return make_mesh({0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 0, 0, 1, 1, 0, 1, 1, 1, 1, 0, 1, 1},
                   {0, 2, 1, 0, 3, 2, 4, 5, 6, 4, 6, 7, 0, 1, 5, 0, 5, 4,
                    2, 3, 7, 2, 7, 6, 1, 2, 6, 1, 6, 5, 0, 4, 7, 0, 7, 3});
}

// A strip of 4 triangles over 6 vertices: each inner triangle has 2
// edge neighbours, the two ends 1.
inline primitives::IndexedMesh strip() {
  return make_mesh({0, 0, 0, 0, 1, 0, 1, 0, 0, 1, 1, 0, 2, 0, 0, 2, 1, 0}, {0, 2, 1, 1, 2, 3, 2, 4, 3, 3, 4, 5});
}

// A bow-tie of pages: three triangles on one edge (0,1), a non-manifold edge.
inline primitives::IndexedMesh three_pages() {
  return make_mesh({0, 0, 0, 1, 0, 0, 0.5f, 1, 0, 0.5f, -1, 0, 0.5f, 0, 1}, {0, 1, 2, 0, 1, 3, 0, 1, 4});
}

}  // namespace flat::test
