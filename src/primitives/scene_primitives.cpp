#include "flat/primitives/scene_primitives.h"

#include "flat/core/error.h"

namespace flat::primitives {

ScenePrimitives ScenePrimitives::of(GaussianSoup g) {
  const int64_t k = g.scale_count();
  FLAT_CHECK(k == 2 || k == 3, "ScenePrimitives: Gaussians need 3 (3DGS) or 2 (2DGS) scales, got " + std::to_string(k));
  return {k == 3 ? kGaussians3d : kSurfels2d, {}, std::move(g)};
}

int64_t ScenePrimitives::batch() const { return is_triangles() ? triangles.batch() : gaussians.batch(); }
int64_t ScenePrimitives::size() const { return opacities().size(-1); }  // batched (B,N) or one scene (N)
at::Tensor ScenePrimitives::opacities() const { return is_triangles() ? triangles.opacities : gaussians.opacities; }

at::Tensor ScenePrimitives::centres() const {
  return is_triangles() ? triangles.vertices.mean(-2) : gaussians.means;
}

ScenePrimitives ScenePrimitives::scene(int64_t b) const {
  if (is_triangles()) return of(triangles.scene(b));
  return {representation, {}, gaussians.scene(b)};
}

std::vector<std::pair<std::string, at::Tensor>> ScenePrimitives::named_tensors() const {
  if (is_triangles())
    return {{"vertices", triangles.vertices}, {"colors", triangles.colors}, {"opacities", triangles.opacities},
            {"sigmas", triangles.sigmas}};
  return {{"means", gaussians.means}, {"scales", gaussians.scales}, {"rotations", gaussians.rotations},
          {"colors", gaussians.colors}, {"opacities", gaussians.opacities}};
}

ScenePrimitives ScenePrimitives::with_tensors(const std::vector<at::Tensor>& t) const {
  const size_t expected = is_triangles() ? 4 : 5;
  FLAT_CHECK(t.size() == expected, "ScenePrimitives::with_tensors: " + representation + " needs " +
                                       std::to_string(expected) + " tensors, got " + std::to_string(t.size()));
  if (is_triangles()) return of(TriangleSoup{t[0], t[1], t[2], t[3]});
  return {representation, {}, GaussianSoup{t[0], t[1], t[2], t[3], t[4]}};
}

ScenePrimitives ScenePrimitives::map(const std::function<at::Tensor(const at::Tensor&)>& f) const {
  std::vector<at::Tensor> out;
  for (const auto& [name, t] : named_tensors()) out.push_back(f(t));
  return with_tensors(out);
}

ScenePrimitives ScenePrimitives::index_select(const at::Tensor& keep) const {
  return map([&](const at::Tensor& t) { return t.index_select(0, keep); });
}

ScenePrimitives cat(const std::vector<ScenePrimitives>& parts, int64_t dim) {
  FLAT_CHECK(!parts.empty(), "cat: no scene parts");
  const size_t n = parts[0].named_tensors().size();
  std::vector<std::vector<at::Tensor>> columns(n);
  for (const auto& p : parts) {
    FLAT_CHECK(p.representation == parts[0].representation, "cat: mixed representations " + p.representation +
                                                                  " and " + parts[0].representation);
    const auto named = p.named_tensors();
    for (size_t i = 0; i < n; ++i) columns[i].push_back(named[i].second);
  }
  std::vector<at::Tensor> joined;
  for (const auto& c : columns) joined.push_back(at::cat(c, dim));
  return parts[0].with_tensors(joined);
}

}  // namespace flat::primitives
