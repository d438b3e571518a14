#include "flat/mesh/boundary_densify.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <utility>
#include <vector>

namespace flat::mesh {

primitives::IndexedMesh densify_boundary(const primitives::IndexedMesh& mesh, double min_edge, int64_t* split_faces) {
  const auto faces = mesh.faces.to(at::kCPU).contiguous();
  const auto xyz_t = mesh.vertices.detach().to(at::kCPU, at::kFloat).contiguous();
  const auto rgb_t = mesh.colors.detach().to(at::kCPU, at::kFloat).contiguous();
  const int64_t nf = faces.size(0);
  const int64_t* f = faces.data_ptr<int64_t>();
  const float* xyz = xyz_t.data_ptr<float>();
  const float* rgb = rgb_t.data_ptr<float>();
  using Edge = std::pair<int64_t, int64_t>;
  const auto edge = [](int64_t a, int64_t b) { return Edge{std::min(a, b), std::max(a, b)}; };
  std::map<Edge, int> uses;
  for (int64_t i = 0; i < nf; ++i)
    for (int k = 0; k < 3; ++k) ++uses[edge(f[3 * i + k], f[3 * i + (k + 1) % 3])];
  const auto length = [&](int64_t a, int64_t b) {
    double s = 0;
    for (int d = 0; d < 3; ++d) s += std::pow(double(xyz[3 * a + d]) - xyz[3 * b + d], 2);
    return std::sqrt(s);
  };

  std::vector<float> out_xyz(xyz, xyz + 3 * mesh.num_vertices()), out_rgb(rgb, rgb + 3 * mesh.num_vertices());
  std::vector<int64_t> out_faces;
  std::map<Edge, int64_t> midpoint;
  const auto mid = [&](int64_t a, int64_t b) {
    const auto key = edge(a, b);
    auto it = midpoint.find(key);
    if (it != midpoint.end()) return it->second;
    const int64_t id = int64_t(out_xyz.size() / 3);
    for (int d = 0; d < 3; ++d) {
      out_xyz.push_back(0.5f * (xyz[3 * a + d] + xyz[3 * b + d]));
      out_rgb.push_back(0.5f * (rgb[3 * a + d] + rgb[3 * b + d]));
    }
    midpoint.emplace(key, id);
    return id;
  };
  int64_t split = 0;
  for (int64_t i = 0; i < nf; ++i) {
    const int64_t a = f[3 * i], b = f[3 * i + 1], c = f[3 * i + 2];
    double longest_open = 0;
    for (int k = 0; k < 3; ++k) {
      const int64_t p = f[3 * i + k], q = f[3 * i + (k + 1) % 3];
      if (uses[edge(p, q)] == 1) longest_open = std::max(longest_open, length(p, q));
    }
    if (longest_open <= min_edge || a == b || b == c || a == c) {
      out_faces.insert(out_faces.end(), {a, b, c});
      continue;
    }
    ++split;
    const int64_t ab = mid(a, b), bc = mid(b, c), ca = mid(c, a);
    // Four children with the parent's winding.
    out_faces.insert(out_faces.end(), {a, ab, ca, ab, b, bc, ca, bc, c, ab, bc, ca});
  }
  if (split_faces) *split_faces = split;
  const int64_t nv = int64_t(out_xyz.size() / 3);
  return {at::from_blob(out_xyz.data(), {nv, 3}, at::kFloat).clone(),
          at::from_blob(out_rgb.data(), {nv, 3}, at::kFloat).clone(),
          at::from_blob(out_faces.data(), {int64_t(out_faces.size() / 3), 3}, at::kLong).clone()};
}

}  // namespace flat::mesh
