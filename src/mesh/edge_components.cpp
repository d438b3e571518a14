#include "flat/mesh/edge_components.h"

#include <algorithm>
#include <tuple>
#include <vector>

#include "union_find.h"

namespace flat::mesh {

at::Tensor edge_connected_labels(const primitives::IndexedMesh& mesh) {
  const auto faces = mesh.faces.to(at::kCPU).contiguous();
  const int64_t nf = faces.size(0);
  const int64_t* f = faces.data_ptr<int64_t>();
  // (a, b, face) with a < b, sorted so that the faces of one edge are adjacent.
  std::vector<std::tuple<int64_t, int64_t, int64_t>> edges;
  edges.reserve(size_t(3 * nf));
  for (int64_t i = 0; i < nf; ++i)
    for (int k = 0; k < 3; ++k) {
      const int64_t a = f[3 * i + k], b = f[3 * i + (k + 1) % 3];
      if (a != b) edges.emplace_back(std::min(a, b), std::max(a, b), i);
    }
  std::sort(edges.begin(), edges.end());
  UnionFind uf(nf);
  for (size_t i = 1; i < edges.size(); ++i) {
    const auto& [a0, b0, f0] = edges[i - 1];
    const auto& [a1, b1, f1] = edges[i];
    if (a0 == a1 && b0 == b1) uf.unite(f0, f1);
  }
  return at::tensor(uf.labels(), at::kLong);
}

int64_t edge_connected_pieces(const primitives::IndexedMesh& mesh) {
  const auto labels = edge_connected_labels(mesh);
  return labels.numel() ? labels.max().item<int64_t>() + 1 : 0;
}

}  // namespace flat::mesh
