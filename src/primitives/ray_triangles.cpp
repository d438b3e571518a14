// Ray-centred triangle parameterisation (paper, Method, "Decoding Triangles")
// and its two ablations (paper, Table "Ablation studies": "3 Offsets" and
// "Global" rotation). Pure ATen: autograd differentiates every step. The
// per-triangle products are small_matmul (flat/core/small_matmul.h): fp32 under the
// training step's bf16 autocast, and no batched GEMM launches.
//
// Per token (b, t, i, j) with anchor ray o + s d through the centre of the 2x2
// block (2i..2i+1, 2j..2j+1) of frame t (camera c = b*T + t):
//
//   centre      c  = o + D d                                   (paper: r_o + D r_d)
//   ray frame   e1 = normalize(x_cam - (x_cam . d) d),  e2 = d x e1,  F = [e1 e2 d]
//               (x_cam = the camera's right axis; (e1, e2, d) is right-handed like
//               the camera's (x, y, z), so e1 ~ image right, e2 ~ image down)
//   footprint   s  = init_scale * sqrt(2) * D / s_min(J1 [e1 e2])
//               J1 = d(pixel)/d(point) of frame t's projection at the point d
//               (unit distance along the ray); s_min its smallest singular
//               value, so a world length s in any tangent direction projects to
//               at least init_scale*sqrt(2) px (to first order).
//   canonical   q_k = 2 (cos a_k, sin a_k), a = 90, -30, -150 deg: centred
//               equilateral triangle, inradius 1, clockwise in (e1, e2) so that
//               (v1 - v0) x (v2 - v0) = -|.| d faces the camera.
//   shape       L = [[L00, 0], [L10, L11]],  L00, L11 = m + softplus(x + b) > 0,
//               b = log(exp(1 - m) - 1) so L = I at x = 0;  L10 = x.
//               area(L q) = det(L) area(q) = L00 L11 3 sqrt(3) > 0  (paper eq. L)
//   rotation    R_res = Rx(tilt_x) Ry(tilt_y) Rz(spin),  tilt = max_tilt tanh(x),
//               spin = x;  F' = F R_res  (zero angles: F' = F, normal = -d)
//   vertices    v_k = c + F'[:, 0:2] (s L q_k)   (centroid of L q_k is 0, so the
//               centroid of the triangle is c, on the anchor ray at depth D)
//
// Ablations:
//   three_offsets:   p_k = s (q_k + delta_k) - mean_k(s (q_k + delta_k)) replaces
//                    s L q_k (six free numbers; can degenerate, that is the point).
//   global_rotation: F' = R(normalize((1,0,0,0) + q_raw)), a world-space rotation
//                    replacing F R_res (the identity lays the triangle in the world
//                    x-y plane, whatever the ray).
#include <cmath>

#include "flat/core/small_matmul.h"
#include "flat/camera/rays.h"
#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/primitives/ray_triangles.h"
#include "primitives/ray_anchors.h"

namespace flat::primitives {
namespace {

at::Tensor activate_sigma(const at::Tensor& x, const TriangleParamConfig& cfg) {
  if (cfg.sigma_activation == "exp") return cfg.sigma_min + (cfg.sigma_init - cfg.sigma_min) * at::exp(x);
  return shifted_softplus(x, cfg.sigma_min, cfg.sigma_init);
}

// Canonical triangle as a (2,3) matrix, columns q_0, q_1, q_2.
at::Tensor canonical_triangle(const at::TensorOptions& opts) {
  const double r3 = std::sqrt(3.0);
  return at::tensor({0.0, r3, -r3, 2.0, -1.0, -1.0}, opts.dtype(at::kDouble)).view({2, 3}).to(opts);
}

// (...,3,3) rotation about one axis (0 = x, 1 = y, 2 = z) by angle a (...).
at::Tensor axis_rotation(const at::Tensor& a, int axis) {
  auto c = at::cos(a), s = at::sin(a), o = at::ones_like(a), z = at::zeros_like(a);
  std::vector<at::Tensor> m;
  if (axis == 0) m = {o, z, z, z, c, -s, z, s, c};
  else if (axis == 1) m = {c, z, s, z, o, z, -s, z, c};
  else m = {c, -s, z, s, c, z, z, z, o};
  return at::stack(m, -1).unflatten(-1, {3, 3});
}

}  // namespace

TriangleSoup build_triangles(const at::Tensor& raw, const camera::Cameras& cams, int64_t image_height,
                             int64_t image_width, const TriangleParamConfig& cfg) {
  cfg.check();
  const HeadChannels ch = cfg.channels();
  const RayAnchors anchors = ray_anchors(raw, ch.total, cams, image_height, image_width, "build_triangles");
  const auto opts = anchors.tokens.options();
  const auto& o = anchors.origins;
  const auto& d = anchors.directions;
  const auto& F = anchors.frames;
  const auto& per_pixel = anchors.per_pixel;
  auto group = [&](int64_t start, int64_t count) { return anchors.tokens.narrow(-1, start, count); };

  auto D = activate_depth(group(ch.depth, 1), cfg);                       // (B,N,1)
  auto centre = o + D * d;                                                // (B,N,3)
  auto s = (cfg.init_scale * std::sqrt(2.0)) * D * per_pixel.unsqueeze(-1);  // (B,N,1)
  auto Q = canonical_triangle(opts);                                      // (2,3)

  // In-plane vertex positions P (B,N,2,3), columns = vertices, centroid 0.
  at::Tensor P;
  if (cfg.parameterisation == "three_offsets") {
    auto delta = group(ch.shape, 6).unflatten(-1, {3, 2}).transpose(-1, -2);  // (B,N,2,3)
    P = s.unsqueeze(-1) * (Q + delta);
    P = P - P.mean(-1, true);
  } else {
    auto l = group(ch.shape, 3);
    auto L00 = shifted_softplus(l.select(-1, 0), cfg.shape_min, 1.0);
    auto L10 = l.select(-1, 1);
    auto L11 = shifted_softplus(l.select(-1, 2), cfg.shape_min, 1.0);
    auto L = at::stack({L00, at::zeros_like(L00), L10, L11}, -1).unflatten(-1, {2, 2});
    P = s.unsqueeze(-1) * small_matmul(L, Q);
  }

  // Orientation F' (B,N,3,3).
  at::Tensor Fr;
  if (cfg.parameterisation == "global_rotation") {
    auto q = group(ch.rotation, 4) + at::tensor({1.0, 0.0, 0.0, 0.0}, opts.dtype(at::kDouble)).to(opts);
    q = q / q.norm(2, -1, true).clamp_min(1e-12);
    Fr = quaternion_to_matrix(q);
  } else {
    auto a = group(ch.rotation, 3);
    auto tilt_x = cfg.max_tilt * at::tanh(a.select(-1, 0));
    auto tilt_y = cfg.max_tilt * at::tanh(a.select(-1, 1));
    auto spin = a.select(-1, 2);
    auto R_res = small_matmul(small_matmul(axis_rotation(tilt_x, 0), axis_rotation(tilt_y, 1)), axis_rotation(spin, 2));
    Fr = small_matmul(F, R_res);
  }

  // v_k = c + F'[:, 0:2] p_k  -> (B,N,3 vertices,3 coords)
  auto V = centre.unsqueeze(-1) + small_matmul(Fr.narrow(-1, 0, 2), P);  // (B,N,3,3) columns = vertices
  TriangleSoup soup;
  soup.vertices = V.transpose(-1, -2).contiguous();
  soup.colors = activate_colour(group(ch.colour, ch.colour_count), cfg).contiguous();
  soup.opacities = at::sigmoid(group(ch.opacity, 1).squeeze(-1) - cfg.opacity_shift).contiguous();
  soup.sigmas = activate_sigma(group(ch.sigma, 1).squeeze(-1), cfg).contiguous();
  return soup;
}

}  // namespace flat::primitives
