#include "flat/mesh/seam_weld.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <tuple>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include <fmt/format.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/mesh/vertex_stitch.h"

namespace flat::mesh {

namespace {

struct Projected {
  double x = 0, y = 0, z = 0;  // sample coordinates (sample u's centre at x = u), camera z-depth
};

// World points (N,3) into the sample grid of the camera.
std::vector<Projected> project(const at::Tensor& xyz_in, const at::Tensor& intrinsics, const at::Tensor& c2w,
                               int64_t H, int64_t W) {
  const auto xyz = xyz_in.detach().to(at::kCPU, at::kDouble).contiguous();
  const auto m_t = c2w.detach().to(at::kCPU, at::kDouble).contiguous().reshape({4, 4});
  const auto k_t = intrinsics.detach().to(at::kCPU, at::kDouble).contiguous().reshape({4});
  const double* m = m_t.data_ptr<double>();
  const double* k = k_t.data_ptr<double>();
  const double* p = xyz.data_ptr<double>();
  const double fx = k[0] * double(W), fy = k[1] * double(H), cx = k[2] * double(W), cy = k[3] * double(H);
  std::vector<Projected> out(size_t(xyz.size(0)));
  for (int64_t i = 0; i < xyz.size(0); ++i) {
    // Camera coordinates: R^T (p - t), the columns of R being the camera axes in the world.
    double c[3];
    for (int a = 0; a < 3; ++a) {
      c[a] = 0;
      for (int r = 0; r < 3; ++r) c[a] += m[4 * r + a] * (p[3 * i + r] - m[4 * r + 3]);
    }
    auto& o = out[size_t(i)];
    o.z = c[2];
    if (c[2] <= 0) continue;
    o.x = fx * c[0] / c[2] + cx - 0.5;
    o.y = fy * c[1] / c[2] + cy - 0.5;
  }
  return out;
}

// Which rim vertex of the mesh each grid vertex on a held sample becomes
// (-1: none): pairs within radius samples in the view and depth_tolerance in
// depth, nearest first, one to one.
std::vector<int64_t> weld_targets(const primitives::IndexedMesh& mesh, const primitives::IndexedMesh& grid,
                                  const at::Tensor& held, const at::Tensor& intrinsics, const at::Tensor& c2w,
                                  const SeamWeldOptions& o) {
  const int64_t H = held.size(0), W = held.size(1);
  const int64_t nm = mesh.num_vertices(), ng = grid.num_vertices();
  const auto held_t = held.to(at::kCPU, at::kBool).contiguous();
  const bool* h = held_t.data_ptr<bool>();
  // The mesh's rim vertices in the new view, bucketed by their nearest sample.
  const auto rim_t = nm > 0 ? boundary_vertices(mesh) : at::zeros({0}, at::kBool);
  const bool* rim = rim_t.data_ptr<bool>();
  const auto mp = project(mesh.vertices, intrinsics, c2w, H, W);
  std::unordered_map<int64_t, std::vector<int64_t>> buckets;
  for (int64_t i = 0; i < nm; ++i) {
    if (!rim[i] || mp[size_t(i)].z <= 0) continue;
    const int64_t u = std::lround(mp[size_t(i)].x), v = std::lround(mp[size_t(i)].y);
    if (u < -1 || v < -1 || u > W || v > H) continue;
    buckets[(v + 1) * (W + 2) + (u + 1)].push_back(i);
  }
  // Candidate pairs (distance in samples, grid vertex, rim vertex): grid vertices on held samples only.
  const auto gp = project(grid.vertices, intrinsics, c2w, H, W);
  std::vector<std::tuple<double, int64_t, int64_t>> pairs;
  const int reach = int(std::ceil(o.radius));
  for (int64_t g = 0; g < ng; ++g) {
    const auto& q = gp[size_t(g)];
    if (q.z <= 0) continue;
    const int64_t u = std::lround(q.x), v = std::lround(q.y);
    if (u < 0 || v < 0 || u >= W || v >= H || !h[v * W + u]) continue;
    for (int64_t dv = -reach; dv <= reach; ++dv)
      for (int64_t du = -reach; du <= reach; ++du) {
        const auto it = buckets.find((v + dv + 1) * (W + 2) + (u + du + 1));
        if (it == buckets.end()) continue;
        for (int64_t b : it->second) {
          const auto& p = mp[size_t(b)];
          const double d = std::hypot(p.x - q.x, p.y - q.y);
          if (d <= o.radius && std::abs(p.z - q.z) <= o.depth_tolerance * q.z) pairs.emplace_back(d, g, b);
        }
      }
  }
  std::sort(pairs.begin(), pairs.end());
  std::vector<int64_t> target(size_t(ng), -1);
  std::vector<char> taken(size_t(nm), 0);
  for (const auto& [d, g, b] : pairs) {
    if (target[size_t(g)] >= 0 || taken[size_t(b)]) continue;
    target[size_t(g)] = b;
    taken[size_t(b)] = 1;
  }
  return target;
}

// Unit normal of the triangle (a, b, c).
void unit_normal(const float* a, const float* b, const float* c, double n[3]) {
  const double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
  n[0] = e1[1] * e2[2] - e1[2] * e2[1];
  n[1] = e1[2] * e2[0] - e1[0] * e2[2];
  n[2] = e1[0] * e2[1] - e1[1] * e2[0];
  const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  for (int d = 0; d < 3; ++d) n[d] = len > 0 ? n[d] / len : 0.0;
}

// The faces of mesh and grid in one index space (grid vertex g is nm + g,
// a welded one its rim vertex). A welded vertex stays welded only if every
// face using it keeps the surface manifold and consistently wound (a shared
// edge runs the other way in its second face) and turns no more than
// max_turn; otherwise the vertices of the face that broke a rule go back to
// their own positions for all their faces (the face overlaps the rim there,
// as before the weld), and the pass repeats until every face fits.
// Only edges between two weld targets can be shared by a new face and a mesh
// face (a new face's other corners are new vertices), so of the mesh only the
// faces with two or more targets enter the edge tables: the fused mesh grows
// to ~0.7 M faces at 432x768, and recording all of them in ordered trees took
// 0.27 s a pass at 0.43 M faces (CPU, 2026-11-28), on every pass of every view.
std::vector<int64_t> seam_faces(const primitives::IndexedMesh& mesh, const primitives::IndexedMesh& grid,
                                std::vector<int64_t>& target, double max_turn, SeamWeldReport& r) {
  const int64_t nm = mesh.num_vertices();
  const auto mf_t = mesh.faces.to(at::kCPU, at::kLong).contiguous();
  const auto gf_t = grid.faces.to(at::kCPU, at::kLong).contiguous();
  const auto mv_t = mesh.vertices.detach().to(at::kCPU, at::kFloat).contiguous();
  const auto gv_t = grid.vertices.detach().to(at::kCPU, at::kFloat).contiguous();
  const int64_t *mf = mf_t.data_ptr<int64_t>(), *gf = gf_t.data_ptr<int64_t>();
  const float *mv = mv_t.data_ptr<float>(), *gv = gv_t.data_ptr<float>();
  const auto at_ = [&](int64_t i) { return i < nm ? mv + 3 * i : gv + 3 * (i - nm); };
  const double min_cos = std::cos(max_turn);
  // An edge a -> b as one key (vertex indices stay below 2^32).
  const auto key = [](int64_t a, int64_t b) { return (uint64_t(a) << 32) | uint64_t(b); };
  std::vector<int64_t> faces;
  std::vector<char> targeted(size_t(nm), 0);
  for (bool again = true; again;) {
    again = false;
    std::unordered_set<uint64_t> directed;
    std::unordered_map<uint64_t, int> uses;
    const auto fits = [&](const int64_t t[3]) {
      if (t[0] == t[1] || t[1] == t[2] || t[2] == t[0]) return false;
      for (int k = 0; k < 3; ++k) {
        const int64_t a = t[k], b = t[(k + 1) % 3];
        const auto u = uses.find(key(std::min(a, b), std::max(a, b)));
        if (directed.count(key(a, b)) || (u != uses.end() && u->second >= 2)) return false;
      }
      return true;
    };
    const auto record_edges = [&](const int64_t t[3]) {
      for (int k = 0; k < 3; ++k) {
        directed.insert(key(t[k], t[(k + 1) % 3]));
        ++uses[key(std::min(t[k], t[(k + 1) % 3]), std::max(t[k], t[(k + 1) % 3]))];
      }
    };
    const auto record = [&](const int64_t t[3]) {
      record_edges(t);
      faces.insert(faces.end(), t, t + 3);
    };
    std::fill(targeted.begin(), targeted.end(), 0);
    for (int64_t b : target)
      if (b >= 0) targeted[size_t(b)] = 1;
    faces.assign(mf, mf + 3 * mesh.num_faces());
    r.dropped_faces = 0;
    for (int64_t i = 0; i < mesh.num_faces(); ++i) {
      const int64_t* t = mf + 3 * i;
      if (targeted[size_t(t[0])] + targeted[size_t(t[1])] + targeted[size_t(t[2])] >= 2) record_edges(t);
    }
    for (int64_t i = 0; i < grid.num_faces(); ++i) {
      const int64_t* g = gf + 3 * i;
      const int64_t t[3] = {target[size_t(g[0])] >= 0 ? target[size_t(g[0])] : nm + g[0],
                            target[size_t(g[1])] >= 0 ? target[size_t(g[1])] : nm + g[1],
                            target[size_t(g[2])] >= 0 ? target[size_t(g[2])] : nm + g[2]};
      double n0[3], n1[3];
      unit_normal(gv + 3 * g[0], gv + 3 * g[1], gv + 3 * g[2], n0);
      unit_normal(at_(t[0]), at_(t[1]), at_(t[2]), n1);
      if (fits(t) && n0[0] * n1[0] + n0[1] * n1[1] + n0[2] * n1[2] >= min_cos) {
        record(t);
        continue;
      }
      bool reverted = false;
      for (int k = 0; k < 3; ++k)
        if (target[size_t(g[k])] >= 0) {
          target[size_t(g[k])] = -1;
          ++r.unwelded_vertices;
          reverted = true;
        }
      if (reverted) again = true;  // this pass is discarded; the next one starts over
      else ++r.dropped_faces;      // not even on its own corners (a grid is manifold: not expected)
    }
  }
  return faces;
}

}  // namespace

primitives::IndexedMesh weld_view_seam(const primitives::IndexedMesh& mesh, const primitives::IndexedMesh& grid,
                                       const at::Tensor& held, const at::Tensor& intrinsics, const at::Tensor& c2w,
                                       const SeamWeldOptions& o, SeamWeldReport* report) {
  FLAT_CHECK(held.dim() == 2, fmt::format("weld_view_seam: held must be (H,W), got {}", shape_str(held)));
  FLAT_CHECK(intrinsics.numel() == 4 && c2w.numel() == 16, "weld_view_seam: intrinsics (4) and c2w (4,4) expected");
  const int64_t nm = mesh.num_vertices(), ng = grid.num_vertices();
  SeamWeldReport r;
  auto target = weld_targets(mesh, grid, held, intrinsics, c2w, o);
  auto faces = seam_faces(mesh, grid, target, o.max_turn, r);
  for (int64_t g = 0; g < ng; ++g) r.welded_vertices += target[size_t(g)] >= 0;

  // The grid's vertices that some kept face still uses, after the mesh's.
  std::vector<int64_t> renumber(size_t(ng), -1);
  std::vector<int64_t> kept;
  for (size_t i = 3 * size_t(mesh.num_faces()); i < faces.size(); ++i) {
    if (faces[i] < nm) continue;
    auto& n = renumber[size_t(faces[i] - nm)];
    if (n < 0) {
      n = nm + int64_t(kept.size());
      kept.push_back(faces[i] - nm);
    }
    faces[i] = n;
  }
  const auto keep = at::tensor(kept, at::kLong);
  primitives::IndexedMesh out{
      at::cat({mesh.vertices.to(at::kCPU, at::kFloat), grid.vertices.to(at::kCPU, at::kFloat).index_select(0, keep)}),
      at::cat({mesh.colors.to(at::kCPU, at::kFloat), grid.colors.to(at::kCPU, at::kFloat).index_select(0, keep)}),
      at::tensor(faces, at::kLong).reshape({-1, 3})};
  if (report) *report = r;
  return out;
}

}  // namespace flat::mesh
