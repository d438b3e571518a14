#include "flat/loss/depth.h"

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::loss {

at::Tensor depth_to_disparity(const at::Tensor& depth, double min_depth) {
  return 1.0 / depth.clamp_min(min_depth);
}

at::Tensor disparity_loss(const at::Tensor& pred_disparity, const at::Tensor& target_disparity,
                          const at::Tensor& mask) {
  FLAT_CHECK(pred_disparity.dim() == 3 || (pred_disparity.dim() == 4 && pred_disparity.size(1) == 1),
             "disparity_loss: expected (V,1,H,W) or (V,H,W) disparity, got " + shape_str(pred_disparity));
  FLAT_CHECK(target_disparity.sizes() == pred_disparity.sizes(),
             "disparity_loss: target " + shape_str(target_disparity) + " does not match prediction " +
                 shape_str(pred_disparity));
  FLAT_CHECK(!mask.defined() || mask.sizes() == pred_disparity.sizes(),
             "disparity_loss: mask " + shape_str(mask) + " does not match prediction " + shape_str(pred_disparity));
  const int64_t V = pred_disparity.size(0);
  auto p = pred_disparity.reshape({V, -1});
  auto g = target_disparity.to(p.dtype()).reshape({V, -1});
  auto m = mask.defined() ? mask.reshape({V, -1}).to(p.dtype()) : at::ones_like(p);
  // Invalid target values must not poison the sums: zero them (their m is 0).
  g = at::where(m > 0, g, at::zeros_like(g));
  auto pm = at::where(m > 0, p, at::zeros_like(p));

  // Normal equations of argmin_{s,t} sum m (s p + t - g)^2 (see depth.h).
  auto a00 = (m * pm * pm).sum(1), a01 = (m * pm).sum(1), a11 = m.sum(1);
  auto b0 = (m * pm * g).sum(1), b1 = (m * g).sum(1);
  auto det = a00 * a11 - a01 * a01;
  // Singular when fewer than 2 valid pixels or p constant over them: s = 0, t = mean g.
  auto scale_of = (a00 * a11).clamp_min(1e-30);
  auto ok = det > 1e-10 * scale_of;
  auto safe_det = at::where(ok, det, at::ones_like(det));
  auto s = at::where(ok, (a11 * b0 - a01 * b1) / safe_det, at::zeros_like(det));
  auto t = at::where(ok, (a00 * b1 - a01 * b0) / safe_det, b1 / a11.clamp_min(1));

  auto residual = (s.unsqueeze(1) * pm + t.unsqueeze(1) - g).abs();
  auto per_image = (m * residual).sum(1) / a11.clamp_min(1);
  auto has = (a11 >= 2).to(p.dtype());
  // Mean over images with >= 2 valid pixels; 0 (still in the graph) if none.
  return (has * per_image).sum() / has.sum().clamp_min(1);
}

}  // namespace flat::loss
