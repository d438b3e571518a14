#include "flat/mesh/vertex_stitch.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <set>
#include <tuple>
#include <vector>

#include <nanoflann.hpp>

#include "flat/core/error.h"

namespace flat::mesh {

namespace {

// nanoflann's dataset interface over a subset of the mesh's vertices.
struct PointSubset {
  const float* xyz;
  std::vector<int64_t> ids;
  size_t kdtree_get_point_count() const { return ids.size(); }
  float kdtree_get_pt(size_t i, size_t d) const { return xyz[3 * ids[i] + d]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const { return false; }
};
using KdTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, PointSubset>, PointSubset, 3,
                                                   uint32_t>;

// Vertices sharing a face with each vertex (sorted), from the faces (F,3).
std::vector<std::vector<int64_t>> face_neighbours(const at::Tensor& faces, int64_t v) {
  std::vector<std::vector<int64_t>> out(static_cast<size_t>(v));
  const int64_t* f = faces.data_ptr<int64_t>();
  for (int64_t i = 0; i < faces.size(0); ++i)
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b)
        if (a != b) out[size_t(f[3 * i + a])].push_back(f[3 * i + b]);
  for (auto& n : out) {
    std::sort(n.begin(), n.end());
    n.erase(std::unique(n.begin(), n.end()), n.end());
  }
  return out;
}

}  // namespace

at::Tensor boundary_vertices(const primitives::IndexedMesh& mesh) {
  const auto faces = mesh.faces.to(at::kCPU).contiguous();
  const int64_t* f = faces.data_ptr<int64_t>();
  std::vector<std::pair<int64_t, int64_t>> edges;
  for (int64_t i = 0; i < faces.size(0); ++i)
    for (int k = 0; k < 3; ++k) {
      const int64_t a = f[3 * i + k], b = f[3 * i + (k + 1) % 3];
      if (a != b) edges.emplace_back(std::min(a, b), std::max(a, b));
    }
  std::sort(edges.begin(), edges.end());
  auto out = at::zeros({mesh.num_vertices()}, at::kBool);
  auto* o = out.data_ptr<bool>();
  for (size_t i = 0; i < edges.size();) {
    size_t j = i;
    while (j < edges.size() && edges[j] == edges[i]) ++j;
    if (j - i == 1) o[edges[i].first] = o[edges[i].second] = true;
    i = j;
  }
  return out;
}

at::Tensor vertex_scales(const primitives::IndexedMesh& mesh) {
  const auto v = mesh.vertices.detach().to(at::kCPU, at::kFloat);
  const auto f = mesh.faces.to(at::kCPU);
  const auto corners = v.index_select(0, f.reshape({-1})).reshape({-1, 3, 3});
  const auto face_size = (corners - corners.roll(1, 1)).norm(2, -1).mean(1);  // (F,)
  auto sum = at::zeros({mesh.num_vertices()}, at::kFloat), count = at::zeros({mesh.num_vertices()}, at::kFloat);
  for (int k = 0; k < 3; ++k) {
    sum.index_add_(0, f.select(1, k), face_size);
    count.index_add_(0, f.select(1, k), at::ones_like(face_size));
  }
  return sum / count.clamp_min(1);
}

at::Tensor nearest_partners(const primitives::IndexedMesh& mesh, const at::Tensor& candidates, const at::Tensor& radius,
                            double max_color_distance) {
  const int64_t v = mesh.num_vertices();
  const auto xyz = mesh.vertices.detach().to(at::kCPU, at::kFloat).contiguous();
  const auto faces = mesh.faces.to(at::kCPU).contiguous();
  const auto rgb_t = mesh.colors.detach().to(at::kCPU, at::kFloat).contiguous();
  const float* rgb = rgb_t.data_ptr<float>();
  const double max_c2 = max_color_distance * max_color_distance;
  const auto colour_ok = [&](int64_t a, int64_t b) {
    if (max_color_distance <= 0) return true;
    double d2 = 0;
    for (int c = 0; c < 3; ++c) d2 += std::pow(double(rgb[3 * a + c]) - rgb[3 * b + c], 2);
    return d2 <= max_c2;
  };
  const auto cand = candidates.to(at::kCPU, at::kBool).contiguous();
  const auto radius_t = radius.to(at::kCPU, at::kFloat).contiguous();
  const float* r = radius_t.data_ptr<float>();
  auto out = at::full({v}, -1, at::kLong);
  PointSubset pts{xyz.data_ptr<float>(), {}};
  for (int64_t i = 0; i < v; ++i)
    if (cand.data_ptr<bool>()[i]) pts.ids.push_back(i);
  if (pts.ids.size() < 2) return out;
  const auto adjacent = face_neighbours(faces, v);
  KdTree tree(3, pts, nanoflann::KDTreeSingleIndexAdaptorParams(16));
  auto* o = out.data_ptr<int64_t>();
  // Enough neighbours to step over the vertex itself, its face mates (a vertex
  // of k faces has up to 2k mates) and colour mismatches; widened when they
  // fill the list. Beyond max_distance nothing qualifies, so the search stops.
  for (int64_t id : pts.ids) {
    const auto& mates = adjacent[size_t(id)];
    const float max_d2 = r[id] * r[id];
    for (size_t k = std::min(pts.ids.size(), mates.size() + 8);; k = std::min(pts.ids.size(), 2 * k)) {
      std::vector<uint32_t> idx(k);
      std::vector<float> d2(k);
      const size_t found = tree.knnSearch(pts.xyz + 3 * id, k, idx.data(), d2.data());
      bool decided = false;
      for (size_t q = 0; q < found && !decided; ++q) {
        const int64_t other = pts.ids[idx[q]];
        if (d2[q] > max_d2) {
          decided = true;  // sorted: everything further is too far as well
          break;
        }
        if (other == id || std::binary_search(mates.begin(), mates.end(), other) || !colour_ok(id, other) ||
            d2[q] > r[other] * r[other])
          continue;
        o[id] = other;
        decided = true;
      }
      if (decided || found < k || k == pts.ids.size()) break;
    }
  }
  return out;
}

primitives::IndexedMesh stitch_boundary_vertices(const primitives::IndexedMesh& mesh, const StitchOptions& o,
                                                 StitchReport* report) {
  primitives::check_mesh(mesh, "stitching");
  StitchReport r;
  auto m = primitives::IndexedMesh{mesh.vertices.detach().to(at::kCPU, at::kFloat).clone(),
                                   mesh.colors.detach().to(at::kCPU, at::kFloat).clone(),
                                   mesh.faces.to(at::kCPU).clone()};
  for (int64_t round = 0; round < o.rounds; ++round) {
    const auto partner =
        nearest_partners(m, boundary_vertices(m), o.distance_factor * vertex_scales(m), o.max_color_distance);
    const int64_t* p = partner.data_ptr<int64_t>();
    const int64_t v = m.num_vertices();
    std::vector<int64_t> remap(static_cast<size_t>(v));
    for (int64_t i = 0; i < v; ++i) remap[size_t(i)] = i;
    float* xyz = m.vertices.data_ptr<float>();
    float* rgb = m.colors.data_ptr<float>();
    int64_t merged = 0;
    for (int64_t a = 0; a < v; ++a) {
      const int64_t b = p[a];
      if (b <= a || p[b] != a) continue;  // mutual pairs, each once
      for (int d = 0; d < 3; ++d) {
        xyz[3 * a + d] = 0.5f * (xyz[3 * a + d] + xyz[3 * b + d]);
        rgb[3 * a + d] = 0.5f * (rgb[3 * a + d] + rgb[3 * b + d]);
      }
      remap[size_t(b)] = a;
      ++merged;
    }
    r.rounds_run = round + 1;
    if (merged == 0) break;
    r.merged_pairs += merged;
    // Renumber faces; drop those that collapsed (a repeated vertex) or now
    // duplicate another face (two triangles merged onto each other).
    const int64_t* f = m.faces.data_ptr<int64_t>();
    std::vector<int64_t> kept;
    std::set<std::array<int64_t, 3>> present;
    for (int64_t i = 0; i < m.num_faces(); ++i) {
      std::array<int64_t, 3> t = {remap[size_t(f[3 * i])], remap[size_t(f[3 * i + 1])], remap[size_t(f[3 * i + 2])]};
      auto key = t;
      std::sort(key.begin(), key.end());
      if (key[0] == key[1] || key[1] == key[2] || !present.insert(key).second) {
        ++r.collapsed_faces;
        continue;
      }
      kept.insert(kept.end(), t.begin(), t.end());
    }
    m.faces = at::tensor(kept, at::kLong).reshape({-1, 3});
    m = primitives::compact_vertices(m);
  }
  if (report) *report = r;
  return m;
}

}  // namespace flat::mesh
