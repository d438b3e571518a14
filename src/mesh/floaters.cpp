#include "flat/mesh/floaters.h"

#include <vector>

#include "flat/mesh/edge_components.h"
#include "union_find.h"

namespace flat::mesh {

at::Tensor face_components(const primitives::IndexedMesh& mesh) {
  const auto faces = mesh.faces.to(at::kCPU).contiguous();
  const int64_t nf = faces.size(0);
  const int64_t* f = faces.data_ptr<int64_t>();
  UnionFind uf(nf);
  std::vector<int64_t> first(size_t(mesh.num_vertices()), -1);
  for (int64_t i = 0; i < 3 * nf; ++i) {
    auto& slot = first[size_t(f[i])];
    if (slot < 0) slot = i / 3;
    else uf.unite(slot, i / 3);
  }
  return at::tensor(uf.labels(), at::kLong);
}

primitives::IndexedMesh remove_small_components(const primitives::IndexedMesh& mesh, int64_t min_faces,
                                                int64_t* removed_faces, bool through_edges) {
  const auto label = through_edges ? edge_connected_labels(mesh) : face_components(mesh);
  const int64_t components = label.numel() ? label.max().item<int64_t>() + 1 : 0;
  const auto sizes = at::bincount(label, {}, components);
  const auto keep = (sizes.index_select(0, label) >= min_faces).nonzero().reshape({-1});
  if (removed_faces) *removed_faces = mesh.num_faces() - keep.numel();
  primitives::IndexedMesh out{mesh.vertices, mesh.colors, mesh.faces.index_select(0, keep.to(mesh.faces.device()))};
  return primitives::compact_vertices(out);
}

}  // namespace flat::mesh
