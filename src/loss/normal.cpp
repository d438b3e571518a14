#include "flat/loss/normal.h"

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::loss {

at::Tensor normal_loss(const at::Tensor& rendered, const at::Tensor& target, const at::Tensor& alpha,
                       double alpha_threshold) {
  check_shape(rendered, {-1, 3, -1, -1}, "normal_loss: rendered normal", "(V,3,H,W)");
  FLAT_CHECK(target.sizes() == rendered.sizes(), "normal_loss: target normal " + shape_str(target) +
                                                     " does not match rendered " + shape_str(rendered));
  check_shape(alpha, {rendered.size(0), 1, rendered.size(2), rendered.size(3)}, "normal_loss: alpha",
              "(V,1,H,W)");
  auto N = target.to(rendered.dtype());
  // M = [alpha > 0.5] and a valid (non-zero) target normal; no gradient through M.
  auto M = ((alpha.detach() > alpha_threshold) & (N.norm(2, 1, true) > 0.5)).to(rendered.dtype());
  auto n = rendered / rendered.norm(2, 1, true).clamp_min(1e-8);
  auto N_unit = N / N.norm(2, 1, true).clamp_min(1e-8);
  auto err = 1 - (n * N_unit).sum(1, true);
  return (M * err).sum() / M.sum().clamp_min(1);
}

}  // namespace flat::loss
