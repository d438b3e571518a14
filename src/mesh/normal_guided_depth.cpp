#include "flat/mesh/normal_guided_depth.h"

#include <cmath>
#include <vector>

#include <fmt/format.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::mesh {

namespace {

// The samples of one view on the CPU: log depth where valid, normals, rays.
struct Samples {
  int64_t H = 0, W = 0;
  std::vector<char> ok;
  std::vector<double> log_depth;  // 0 where not ok
  const float* normals = nullptr; // (3,H,W)
  double fx = 0, fy = 0, cx = 0, cy = 0;

  int64_t count() const { return H * W; }
  // The unit ray through sample p's centre.
  void ray(int64_t p, double r[3]) const {
    r[0] = (double(p % W) + 0.5 - cx) / fx;
    r[1] = (double(p / W) + 0.5 - cy) / fy;
    r[2] = 1.0;
    const double len = std::sqrt(r[0] * r[0] + r[1] * r[1] + 1.0);
    for (int d = 0; d < 3; ++d) r[d] /= len;
  }
};

struct Link {
  int64_t p, q;  // samples; the link asks l_q - l_p = step
  double step;
};

// The step in log depth from p to q of a plane with p's and q's mean normal;
// false where there is no normal, or a ray meets the plane edge-on.
bool plane_step(const Samples& s, int64_t p, int64_t q, double& step) {
  const int64_t P = s.count();
  double m[3], rp[3], rq[3];
  for (int d = 0; d < 3; ++d) m[d] = double(s.normals[d * P + p]) + double(s.normals[d * P + q]);
  const double len = std::sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
  if (len < 1e-6) return false;
  s.ray(p, rp);
  s.ray(q, rq);
  const double cp = (m[0] * rp[0] + m[1] * rp[1] + m[2] * rp[2]) / len;
  const double cq = (m[0] * rq[0] + m[1] * rq[1] + m[2] * rq[2]) / len;
  if (cp * cq <= 0 || std::abs(cp) < 0.05 || std::abs(cq) < 0.05) return false;
  // On the plane n.X = c, X = z (x, y, 1): z = c / (n.(x,y,1)), and n.(x,y,1) = (n.r) / r_z for the unit ray r.
  step = std::log(std::abs(cp) / rp[2]) - std::log(std::abs(cq) / rq[2]);
  return true;
}

// Links between right and down neighbours, cut across discontinuities.
std::vector<Link> plane_links(const Samples& s, double max_step) {
  std::vector<Link> links;
  const auto link = [&](int64_t p, int64_t q) {
    double step = 0;
    if (!s.ok[size_t(p)] || !s.ok[size_t(q)] || !plane_step(s, p, q, step)) return;
    if (std::abs(s.log_depth[size_t(q)] - s.log_depth[size_t(p)] - step) > max_step) return;
    links.push_back({p, q, step});
  };
  for (int64_t v = 0; v < s.H; ++v)
    for (int64_t u = 0; u < s.W; ++u) {
      const int64_t p = v * s.W + u;
      if (u + 1 < s.W) link(p, p + 1);
      if (v + 1 < s.H) link(p, p + s.W);
    }
  return links;
}

// Least squares by conjugate gradients on the normal equations A l = b,
// A = depth_weight I + the links' graph Laplacian, from the rendered log depth.
std::vector<double> solve(const Samples& s, const std::vector<Link>& links, double wd, int64_t iterations) {
  const auto n = static_cast<size_t>(s.count());
  std::vector<double> b(n, 0.0);
  for (size_t p = 0; p < n; ++p) b[p] = wd * s.log_depth[p];
  for (const auto& e : links) {
    b[size_t(e.q)] += e.step;
    b[size_t(e.p)] -= e.step;
  }
  const auto apply = [&](const std::vector<double>& x, std::vector<double>& y) {
    for (size_t p = 0; p < n; ++p) y[p] = s.ok[p] ? wd * x[p] : 0.0;
    for (const auto& e : links) {
      const double d = x[size_t(e.q)] - x[size_t(e.p)];
      y[size_t(e.q)] += d;
      y[size_t(e.p)] -= d;
    }
  };
  std::vector<double> x = s.log_depth, r(n), d(n), ad(n);
  apply(x, ad);
  double rr = 0, bb = 0;
  for (size_t p = 0; p < n; ++p) {
    r[p] = s.ok[p] ? b[p] - ad[p] : 0.0;
    d[p] = r[p];
    rr += r[p] * r[p];
    bb += b[p] * b[p];
  }
  for (int64_t it = 0; it < iterations && rr > 1e-12 * std::max(bb, 1e-30); ++it) {
    apply(d, ad);
    double dad = 0;
    for (size_t p = 0; p < n; ++p) dad += d[p] * ad[p];
    if (dad <= 0) break;
    const double alpha = rr / dad;
    double next = 0;
    for (size_t p = 0; p < n; ++p) {
      x[p] += alpha * d[p];
      r[p] -= alpha * ad[p];
      next += r[p] * r[p];
    }
    for (size_t p = 0; p < n; ++p) d[p] = r[p] + next / rr * d[p];
    rr = next;
  }
  return x;
}

}  // namespace

at::Tensor normal_guided_depth(const at::Tensor& depth, const at::Tensor& normals, const at::Tensor& valid,
                               const at::Tensor& intrinsics, const NormalGuidedDepthOptions& o) {
  FLAT_CHECK(depth.dim() == 2, fmt::format("normal_guided_depth: depth must be (H,W), got {}", shape_str(depth)));
  const int64_t H = depth.size(0), W = depth.size(1);
  FLAT_CHECK(normals.dim() == 3 && normals.size(0) == 3 && normals.size(1) == H && normals.size(2) == W,
             fmt::format("normal_guided_depth: normals must be (3,{},{}), got {}", H, W, shape_str(normals)));
  FLAT_CHECK(valid.sizes() == depth.sizes(),
             fmt::format("normal_guided_depth: valid must be (H,W), got {}", shape_str(valid)));
  FLAT_CHECK(intrinsics.numel() == 4, "normal_guided_depth: intrinsics (4) expected");
  FLAT_CHECK(o.depth_weight > 0 && o.max_step > 0, "normal_guided_depth: depth_weight and max_step must be positive");
  const auto z_t = depth.detach().to(at::kCPU, at::kFloat).contiguous();
  const auto n_t = normals.detach().to(at::kCPU, at::kFloat).contiguous();
  const auto ok_t = (valid.to(at::kCPU, at::kBool) & (z_t > 0)).contiguous();
  const auto k_t = intrinsics.detach().to(at::kCPU, at::kDouble).contiguous().reshape({4});
  const double* k = k_t.data_ptr<double>();
  Samples s;
  s.H = H;
  s.W = W;
  s.normals = n_t.data_ptr<float>();
  s.fx = k[0] * double(W), s.fy = k[1] * double(H), s.cx = k[2] * double(W), s.cy = k[3] * double(H);
  s.ok.assign(ok_t.data_ptr<bool>(), ok_t.data_ptr<bool>() + H * W);
  s.log_depth.assign(size_t(H * W), 0.0);
  const float* z = z_t.data_ptr<float>();
  for (int64_t p = 0; p < H * W; ++p)
    if (s.ok[size_t(p)]) s.log_depth[size_t(p)] = std::log(double(z[p]));

  const auto l = solve(s, plane_links(s, o.max_step), o.depth_weight, o.iterations);
  auto out = z_t.clone();
  float* d = out.data_ptr<float>();
  for (int64_t p = 0; p < H * W; ++p)
    if (s.ok[size_t(p)]) d[p] = float(std::exp(l[size_t(p)]));
  return out;
}

}  // namespace flat::mesh
