#include "flat/mesh/depth_grid_mesh.h"

#include <array>
#include <cmath>
#include <vector>

#include <fmt/format.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::mesh {

primitives::IndexedMesh depth_grid_mesh(const at::Tensor& depth, const at::Tensor& rgb, const at::Tensor& valid,
                                        const at::Tensor& intrinsics, const at::Tensor& c2w,
                                        const DepthGridOptions& o, const at::Tensor& skip) {
  FLAT_CHECK(depth.dim() == 2, fmt::format("depth_grid_mesh: depth must be (H,W), got {}", shape_str(depth)));
  const int64_t H = depth.size(0), W = depth.size(1);
  FLAT_CHECK(rgb.dim() == 3 && rgb.size(0) == 3 && rgb.size(1) == H && rgb.size(2) == W,
             fmt::format("depth_grid_mesh: rgb must be (3,{},{}), got {}", H, W, shape_str(rgb)));
  FLAT_CHECK(valid.sizes() == depth.sizes(), fmt::format("depth_grid_mesh: valid must be (H,W), got {}", shape_str(valid)));
  FLAT_CHECK(!skip.defined() || skip.sizes() == depth.sizes(),
             fmt::format("depth_grid_mesh: skip must be (H,W), got {}", shape_str(skip)));
  FLAT_CHECK(intrinsics.numel() == 4 && c2w.numel() == 16, "depth_grid_mesh: intrinsics (4) and c2w (4,4) expected");
  const auto z_t = depth.detach().to(at::kCPU, at::kFloat).contiguous();
  const auto c_t = rgb.detach().to(at::kCPU, at::kFloat).contiguous();
  const auto ok_t = (valid.to(at::kCPU, at::kBool) & (z_t > 0)).contiguous();
  const auto skip_t = skip.defined() ? skip.to(at::kCPU, at::kBool).contiguous() : at::zeros({H, W}, at::kBool);
  const auto k_t = intrinsics.detach().to(at::kCPU, at::kDouble).contiguous().reshape({4});
  const auto m_t = c2w.detach().to(at::kCPU, at::kDouble).contiguous().reshape({4, 4});
  const float* z = z_t.data_ptr<float>();
  const float* c = c_t.data_ptr<float>();
  const bool* ok = ok_t.data_ptr<bool>();
  const bool* sk = skip_t.data_ptr<bool>();
  const double* k = k_t.data_ptr<double>();
  const double* m = m_t.data_ptr<double>();
  const double fx = k[0] * double(W), fy = k[1] * double(H), cx = k[2] * double(W), cy = k[3] * double(H);
  const double f = 0.5 * (fx + fy);

  // Vertices: every valid pixel, unprojected through its centre.
  std::vector<int64_t> id(size_t(H * W), -1);
  std::vector<float> xyz, col;
  for (int64_t v = 0; v < H; ++v)
    for (int64_t u = 0; u < W; ++u) {
      const int64_t p = v * W + u;
      if (!ok[p]) continue;
      const double zc = z[p], xc = (double(u) + 0.5 - cx) / fx * zc, yc = (double(v) + 0.5 - cy) / fy * zc;
      id[size_t(p)] = int64_t(xyz.size() / 3);
      for (int r = 0; r < 3; ++r) {
        xyz.push_back(float(m[4 * r] * xc + m[4 * r + 1] * yc + m[4 * r + 2] * zc + m[4 * r + 3]));
        col.push_back(c[r * H * W + p]);
      }
    }
  const auto dist = [&](int64_t a, int64_t b) {
    double s = 0;
    for (int d = 0; d < 3; ++d) s += std::pow(double(xyz[size_t(3 * a + d)]) - xyz[size_t(3 * b + d)], 2);
    return std::sqrt(s);
  };
  std::vector<int64_t> faces;
  // Pixel indices p (image order); keeps a triangle if all three exist, not
  // all skipped, and no edge stretches across a discontinuity.
  const auto add = [&](int64_t p0, int64_t p1, int64_t p2) {
    const int64_t a = id[size_t(p0)], b = id[size_t(p1)], cc = id[size_t(p2)];
    if (a < 0 || b < 0 || cc < 0) return;
    if (sk[p0] && sk[p1] && sk[p2]) return;
    const double footprint = (z[p0] + z[p1] + z[p2]) / (3.0 * f);
    const double longest = std::max({dist(a, b), dist(b, cc), dist(cc, a)});
    if (longest > o.max_stretch * footprint) return;
    faces.insert(faces.end(), {a, b, cc});
  };
  for (int64_t v = 0; v + 1 < H; ++v)
    for (int64_t u = 0; u + 1 < W; ++u) {
      const int64_t p00 = v * W + u, p01 = p00 + 1, p10 = p00 + W, p11 = p10 + 1;
      const int64_t i00 = id[size_t(p00)], i01 = id[size_t(p01)], i10 = id[size_t(p10)], i11 = id[size_t(p11)];
      // (down) x (right) = -z in OpenCV camera axes: (p00, p10, p01) faces the camera.
      if (i00 >= 0 && i01 >= 0 && i10 >= 0 && i11 >= 0) {
        // The shorter diagonal: it follows a crease instead of cutting across it.
        if (dist(i00, i11) <= dist(i10, i01)) {
          add(p00, p10, p11);
          add(p00, p11, p01);
        } else {
          add(p00, p10, p01);
          add(p10, p11, p01);
        }
      } else {  // three corners: the one triangle they make
        if (i11 < 0) add(p00, p10, p01);
        else if (i00 < 0) add(p10, p11, p01);
        else if (i01 < 0) add(p00, p10, p11);
        else add(p00, p11, p01);
      }
    }
  primitives::IndexedMesh out{at::tensor(xyz, at::kFloat).reshape({-1, 3}), at::tensor(col, at::kFloat).reshape({-1, 3}),
                              at::tensor(faces, at::kLong).reshape({-1, 3})};
  return primitives::compact_vertices(out);
}

}  // namespace flat::mesh
