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

  // argmin_{s,t} sum m (s p + t - g)^2 (see depth.h), solved on values
  // centred per image: s = sum m (p - p_mean)(g - g_mean) / sum m (p - p_mean)^2,
  // t = g_mean - s p_mean. The uncentred normal equations lose every digit in
  // float32 when p is nearly constant (a wall at 10 m +-1% was off by 16%).
  auto n = m.sum(1);
  auto n_safe = n.clamp_min(1);
  auto p_mean = (m * pm).sum(1) / n_safe, g_mean = (m * g).sum(1) / n_safe;
  auto pc = m * (pm - p_mean.unsqueeze(1)), gc = m * (g - g_mean.unsqueeze(1));
  auto spp = (pc * pc).sum(1), spg = (pc * gc).sum(1);
  // Singular when fewer than 2 valid pixels or p constant over them: s = 0, t = mean g.
  auto ok = spp > 1e-10 * (m * pm * pm).sum(1).clamp_min(1e-30);
  auto s = at::where(ok, spg / at::where(ok, spp, at::ones_like(spp)), at::zeros_like(spp));

  auto residual = (s.unsqueeze(1) * pc - gc).abs();
  auto per_image = (m * residual).sum(1) / n_safe;
  auto has = (n >= 2).to(p.dtype());
  // Mean over images with >= 2 valid pixels; 0 (still in the graph) if none.
  return (has * per_image).sum() / has.sum().clamp_min(1);
}

}  // namespace flat::loss
