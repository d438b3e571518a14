#include "flat/loss/regularisers_2dgs.h"

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::loss {

at::Tensor normals_from_depth(const at::Tensor& depth, const at::Tensor& intrinsics) {
  check_shape(depth, {-1, 1, -1, -1}, "normals_from_depth: depth", "(V,1,H,W)");
  check_shape(intrinsics, {depth.size(0), 4}, "normals_from_depth: intrinsics", "(V,4) normalised fx,fy,cx,cy");
  const int64_t V = depth.size(0), H = depth.size(2), W = depth.size(3);
  FLAT_CHECK(H >= 3 && W >= 3, "normals_from_depth: depth must be at least 3x3, got " + shape_str(depth));
  const auto opts = depth.options();
  auto K = intrinsics.to(opts);
  auto fx = (K.select(1, 0) * W).view({V, 1, 1}), fy = (K.select(1, 1) * H).view({V, 1, 1});
  auto cx = (K.select(1, 2) * W).view({V, 1, 1}), cy = (K.select(1, 3) * H).view({V, 1, 1});
  auto u = at::arange(W, opts).add(0.5).view({1, 1, W});
  auto v = at::arange(H, opts).add(0.5).view({1, H, 1});
  auto z = depth.select(1, 0);  // (V,H,W)
  auto P = at::stack({(u - cx) / fx * z, (v - cy) / fy * z, z}, 1);  // (V,3,H,W) camera space
  // Central differences on the interior.
  auto du = P.narrow(3, 2, W - 2).narrow(2, 1, H - 2) - P.narrow(3, 0, W - 2).narrow(2, 1, H - 2);
  auto dv = P.narrow(2, 2, H - 2).narrow(3, 1, W - 2) - P.narrow(2, 0, H - 2).narrow(3, 1, W - 2);
  auto n = at::cross(dv, du, 1);  // dv x du: (0,0,-1) for a fronto-parallel plane (faces the camera)
  n = n / n.norm(2, 1, true).clamp_min(1e-12);
  return at::constant_pad_nd(n, {1, 1, 1, 1}, 0.0);
}

at::Tensor normal_consistency_loss(const at::Tensor& normal, const at::Tensor& depth, const at::Tensor& alpha,
                                   const at::Tensor& intrinsics) {
  check_shape(normal, {depth.size(0), 3, depth.size(2), depth.size(3)}, "normal_consistency_loss: normal",
              "(V,3,H,W)");
  check_shape(alpha, {depth.size(0), 1, depth.size(2), depth.size(3)}, "normal_consistency_loss: alpha",
              "(V,1,H,W)");
  const int64_t H = depth.size(2), W = depth.size(3);
  auto N = normals_from_depth(depth, intrinsics) * alpha.detach().to(depth.dtype());
  auto err = 1 - (normal.to(depth.dtype()) * N).sum(1);  // (V,H,W)
  return err.narrow(1, 1, H - 2).narrow(2, 1, W - 2).mean();
}

at::Tensor depth_distortion_loss(const at::Tensor& distortion) {
  check_shape(distortion, {-1, 1, -1, -1}, "depth_distortion_loss: distortion map", "(V,1,H,W)");
  return distortion.mean();
}

at::Tensor depth_distortion_reference(const at::Tensor& weights, const at::Tensor& depths, double near,
                                      double far) {
  check_shape(weights, {-1, -1}, "depth_distortion_reference: weights", "(P,K)");
  FLAT_CHECK(depths.sizes() == weights.sizes(), "depth_distortion_reference: depths " + shape_str(depths) +
                                                    " do not match weights " + shape_str(weights));
  FLAT_CHECK(far > near && near > 0, "depth_distortion_reference: need 0 < near < far");
  auto m = (far * depths - far * near) / ((far - near) * depths);
  auto pair = weights.unsqueeze(2) * weights.unsqueeze(1) * (m.unsqueeze(2) - m.unsqueeze(1)).square();
  return 0.5 * pair.sum({1, 2});  // all ordered pairs / 2 = pairs j < i (the diagonal is 0)
}

}  // namespace flat::loss
