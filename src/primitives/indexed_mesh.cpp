#include "flat/primitives/indexed_mesh.h"

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::primitives {

IndexedMesh mesh_from_soup(const TriangleSoup& scene) {
  check_shape(scene.vertices, {-1, 3, 3}, "mesh_from_soup: vertices", "(N,3,3)");
  const int64_t n = scene.vertices.size(0);
  check_shape(scene.colors, {n, 3}, "mesh_from_soup: colors", "(N,3) RGB");
  IndexedMesh m;
  m.vertices = scene.vertices.detach().reshape({3 * n, 3}).to(at::kFloat).contiguous();
  m.colors = scene.colors.detach().to(at::kFloat).unsqueeze(1).expand({n, 3, 3}).reshape({3 * n, 3}).contiguous();
  m.faces = at::arange(3 * n, scene.vertices.options().dtype(at::kLong)).reshape({n, 3});
  return m;
}

TriangleSoup soup_from_mesh(const IndexedMesh& mesh, double opacity, double sigma) {
  const int64_t f = mesh.num_faces();
  const auto flat = mesh.faces.reshape({-1});
  TriangleSoup s;
  s.vertices = mesh.vertices.index_select(0, flat).reshape({f, 3, 3});
  s.colors = mesh.colors.index_select(0, flat).reshape({f, 3, 3}).mean(1);
  s.opacities = at::full({f}, opacity, mesh.vertices.options());
  s.sigmas = at::full({f}, sigma, mesh.vertices.options());
  return s;
}

IndexedMesh compact_vertices(const IndexedMesh& mesh) {
  const int64_t v = mesh.num_vertices();
  auto used = at::zeros({v}, mesh.faces.options().dtype(at::kBool));
  if (mesh.num_faces() > 0) used.index_fill_(0, mesh.faces.reshape({-1}), true);
  const auto keep = used.nonzero().reshape({-1});
  auto remap = at::full({v}, -1, mesh.faces.options());
  remap.index_copy_(0, keep, at::arange(keep.size(0), mesh.faces.options()));
  return {mesh.vertices.index_select(0, keep), mesh.colors.index_select(0, keep),
          remap.index_select(0, mesh.faces.reshape({-1})).reshape({-1, 3})};
}

void check_mesh(const IndexedMesh& m, const std::string& what) {
  check_shape(m.vertices, {-1, 3}, what + ": vertices", "(V,3)");
  check_shape(m.colors, {m.vertices.size(0), 3}, what + ": colors", "(V,3)");
  check_shape(m.faces, {-1, 3}, what + ": faces", "(F,3)");
  FLAT_CHECK(m.faces.scalar_type() == at::kLong, what + ": faces must be int64");
  check_finite(m.vertices, what + ": vertices");
  check_finite(m.colors, what + ": colors");
  if (m.faces.numel() > 0) {
    const int64_t lo = m.faces.min().item<int64_t>(), hi = m.faces.max().item<int64_t>();
    FLAT_CHECK(lo >= 0 && hi < m.vertices.size(0), what + ": face index out of range [" + std::to_string(lo) + ", " +
                                                       std::to_string(hi) + "] for " +
                                                       std::to_string(m.vertices.size(0)) + " vertices");
  }
}

}  // namespace flat::primitives
