#include "flat/mesh/mesh_smoothness.h"

#include <algorithm>
#include <tuple>
#include <vector>

namespace flat::mesh {

at::Tensor edge_adjacent_face_pairs(const at::Tensor& faces_in) {
  const auto faces = faces_in.to(at::kCPU, at::kLong).contiguous();
  const int64_t nf = faces.size(0);
  const int64_t* f = faces.data_ptr<int64_t>();
  std::vector<std::tuple<int64_t, int64_t, int64_t>> edges;
  for (int64_t i = 0; i < nf; ++i)
    for (int k = 0; k < 3; ++k) {
      const int64_t a = f[3 * i + k], b = f[3 * i + (k + 1) % 3];
      if (a != b) edges.emplace_back(std::min(a, b), std::max(a, b), i);
    }
  std::sort(edges.begin(), edges.end());
  std::vector<int64_t> pairs;
  for (size_t i = 0; i < edges.size();) {
    size_t j = i;
    while (j < edges.size() && std::get<0>(edges[j]) == std::get<0>(edges[i]) &&
           std::get<1>(edges[j]) == std::get<1>(edges[i]))
      ++j;
    for (size_t p = i; p < j; ++p)
      for (size_t q = p + 1; q < j; ++q)
        if (std::get<2>(edges[p]) != std::get<2>(edges[q]))
          pairs.insert(pairs.end(), {std::get<2>(edges[p]), std::get<2>(edges[q])});
    i = j;
  }
  return at::tensor(pairs, at::kLong).reshape({-1, 2});
}

at::Tensor normal_consistency(const at::Tensor& vertices, const at::Tensor& faces, const at::Tensor& pairs) {
  if (pairs.size(0) == 0) return at::zeros({}, vertices.options());
  const auto f = faces.to(vertices.device());
  const auto corners = vertices.index_select(0, f.reshape({-1})).reshape({-1, 3, 3});
  const auto n = at::cross(corners.select(1, 1) - corners.select(1, 0), corners.select(1, 2) - corners.select(1, 0), -1);
  const auto unit = n / n.norm(2, -1, true).clamp_min(1e-12);
  const auto p = pairs.to(vertices.device());
  const auto na = unit.index_select(0, p.select(1, 0)), nb = unit.index_select(0, p.select(1, 1));
  return (1 - (na * nb).sum(-1)).mean();
}

}  // namespace flat::mesh
