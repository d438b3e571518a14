// The anchor rays shared by every pixel-aligned primitive (ray_anchors.h).
#include "primitives/ray_anchors.h"

#include <cmath>
#include <vector>

#include "flat/core/small_matmul.h"
#include "flat/camera/rays.h"
#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::primitives {
namespace {

// Ray frame and footprint per anchor ray, all camera-dependent (no gradient
// flows into cameras). d_cam: (B,N,3) unit directions in camera space;
// K: (B,N,4) full-resolution pixel fx, fy, cx, cy.
// Returns F_cam (B,N,3,3) columns e1, e2, d and the world length per unit depth
// that projects to one pixel in the least-stretched tangent direction.
std::pair<at::Tensor, at::Tensor> ray_frame_and_footprint(const at::Tensor& d_cam, const at::Tensor& K) {
  auto dx = d_cam.select(-1, 0), dy = d_cam.select(-1, 1), dz = d_cam.select(-1, 2);
  // e1 = normalize(x - (x.d) d) = normalize((1 - dx^2, -dx dy, -dx dz))
  auto e1 = at::stack({1 - dx * dx, -dx * dy, -dx * dz}, -1);
  e1 = e1 / e1.norm(2, -1, true);
  auto e2 = at::cross(d_cam, e1, -1);
  auto F = at::stack({e1, e2, d_cam}, -1);  // columns
  // J1 e = (1/dz) (fx (e_x - e_z dx/dz), fy (e_y - e_z dy/dz)) for e in {e1, e2}
  auto fx = K.select(-1, 0), fy = K.select(-1, 1);
  auto proj = [&](const at::Tensor& e) {
    auto ex = e.select(-1, 0), ey = e.select(-1, 1), ez = e.select(-1, 2);
    return std::make_pair(fx * (ex - ez * dx / dz) / dz, fy * (ey - ez * dy / dz) / dz);
  };
  auto [m00, m10] = proj(e1);
  auto [m01, m11] = proj(e2);
  // smallest eigenvalue of M^T M = [[a, b], [b, c]]
  auto a = m00 * m00 + m10 * m10, c = m01 * m01 + m11 * m11, b = m00 * m01 + m10 * m11;
  auto lam = 0.5 * (a + c) - at::sqrt(0.25 * (a - c) * (a - c) + b * b);
  auto per_pixel = 1.0 / at::sqrt(lam.clamp_min(1e-30));
  return {F, per_pixel};
}

}  // namespace

// softplus(x + b) + lo with b such that the value at x = 0 is `at_zero`.
at::Tensor shifted_softplus(const at::Tensor& x, double lo, double at_zero) {
  const double b = std::log(std::expm1(at_zero - lo));
  return at::softplus(x + b) + lo;
}

at::Tensor activate_depth(const at::Tensor& x, const TriangleParamConfig& cfg) {
  if (cfg.depth_activation == "sigmoid") {
    auto w = at::sigmoid(x - cfg.depth_shift);
    return cfg.depth_near * (1 - w) + cfg.depth_far * w;
  }
  if (cfg.depth_activation == "exp") return cfg.depth_near + (cfg.depth_init - cfg.depth_near) * at::exp(x);
  return shifted_softplus(x, cfg.depth_near, cfg.depth_init);
}

at::Tensor activate_colour(const at::Tensor& x, const TriangleParamConfig& cfg) {
  if (cfg.colour_activation == "sigmoid") return at::sigmoid(x);
  if (cfg.colour_activation == "tanh") return 0.5 * at::tanh(x) + 0.5;
  // "sh": (B,N,3K) coefficient-major -> (B,N,K,3) raw coefficients.
  return x.unflatten(-1, {sh_coefficient_count(cfg.sh_degree), 3});
}

// (...,4) quaternion (w,x,y,z), unit, -> (...,3,3) rotation matrix.
at::Tensor quaternion_to_matrix(const at::Tensor& q) {
  auto w = q.select(-1, 0), x = q.select(-1, 1), y = q.select(-1, 2), z = q.select(-1, 3);
  std::vector<at::Tensor> m = {1 - 2 * (y * y + z * z), 2 * (x * y - w * z),     2 * (x * z + w * y),
                               2 * (x * y + w * z),     1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                               2 * (x * z - w * y),     2 * (y * z + w * x),     1 - 2 * (x * x + y * y)};
  return at::stack(m, -1).unflatten(-1, {3, 3});
}

at::Tensor matrix_to_quaternion(const at::Tensor& R) {
  auto r = [&](int i, int j) { return R.select(-2, i).select(-1, j); };
  // |w|, |x|, |y|, |z| from the diagonal; signs of x, y, z from the
  // antisymmetric part (w >= 0). Only used on camera frames (no gradient).
  auto half_sqrt = [](const at::Tensor& t) { return 0.5 * at::sqrt(t.clamp_min(0)); };
  auto w = half_sqrt(1 + r(0, 0) + r(1, 1) + r(2, 2));
  auto x = at::copysign(half_sqrt(1 + r(0, 0) - r(1, 1) - r(2, 2)), r(2, 1) - r(1, 2));
  auto y = at::copysign(half_sqrt(1 - r(0, 0) + r(1, 1) - r(2, 2)), r(0, 2) - r(2, 0));
  auto z = at::copysign(half_sqrt(1 - r(0, 0) - r(1, 1) + r(2, 2)), r(1, 0) - r(0, 1));
  auto q = at::stack({w, x, y, z}, -1);
  return q / q.norm(2, -1, true).clamp_min(1e-12);
}

at::Tensor quaternion_multiply(const at::Tensor& a, const at::Tensor& b) {
  auto aw = a.select(-1, 0), ax = a.select(-1, 1), ay = a.select(-1, 2), az = a.select(-1, 3);
  auto bw = b.select(-1, 0), bx = b.select(-1, 1), by = b.select(-1, 2), bz = b.select(-1, 3);
  return at::stack({aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                    aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw},
                   -1);
}

RayAnchors ray_anchors(const at::Tensor& raw, int64_t channels, const camera::Cameras& cams, int64_t image_height,
                       int64_t image_width, const std::string& what) {
  check_shape(raw, {-1, channels, -1, -1, -1}, what + ": raw head output",
              "(B," + std::to_string(channels) + ",T,H/2,W/2)");
  FLAT_CHECK(raw.is_floating_point(), what + ": raw head output must be floating point");
  FLAT_CHECK(image_height % 2 == 0 && image_width % 2 == 0,
             what + ": image size must be even, got " + std::to_string(image_height) + "x" + std::to_string(image_width));
  const int64_t B = raw.size(0), T = raw.size(2), H2 = raw.size(3), W2 = raw.size(4);
  FLAT_CHECK(H2 == image_height / 2 && W2 == image_width / 2,
             what + ": raw grid " + shape_str(raw) + " is not half of the image size " + std::to_string(image_height) +
                 "x" + std::to_string(image_width));
  FLAT_CHECK(cams.size() == B * T, what + ": expected B*T = " + std::to_string(B * T) +
                                       " cameras (frame-major per batch), got " + std::to_string(cams.size()));
  const int64_t N = T * H2 * W2;
  // Geometry in fp32 (fp64 for fp64 input) whatever the model's precision, and
  // whatever autocast is on: the products are small_matmul, never at::matmul.
  const auto dtype = raw.scalar_type() == at::kDouble ? at::kDouble : at::kFloat;
  const auto opts = raw.options().dtype(dtype);

  // Anchor rays through the 2x2 block centres = pixel rays at half resolution.
  auto rays = camera::pixel_rays(cams, H2, W2);
  RayAnchors a;
  a.origins = rays.origins.to(opts).reshape({B, N, 3});
  a.directions = rays.directions.to(opts).reshape({B, N, 3});
  auto R = cams.c2w.to(opts).narrow(1, 0, 3).narrow(2, 0, 3).view({B, T, 1, 3, 3});
  R = R.expand({B, T, H2 * W2, 3, 3}).reshape({B, N, 3, 3});
  auto K = camera::pixel_intrinsics(cams.intrinsics.to(opts), image_height, image_width).view({B, T, 1, 4});
  K = K.expand({B, T, H2 * W2, 4}).reshape({B, N, 4});
  auto d_cam = small_matmul(R.transpose(-1, -2), a.directions.unsqueeze(-1)).squeeze(-1);
  auto [F_cam, per_pixel] = ray_frame_and_footprint(d_cam, K);
  a.frames = small_matmul(R, F_cam);  // ray frame in world space, columns e1, e2, d
  a.per_pixel = per_pixel;
  // (B,C,T,H2,W2) -> (B,N,C), token order (t, i, j)
  a.tokens = raw.to(dtype).permute({0, 2, 3, 4, 1}).reshape({B, N, channels});
  return a;
}

}  // namespace flat::primitives
