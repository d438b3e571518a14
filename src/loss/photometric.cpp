#include "flat/loss/photometric.h"

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::loss {

at::Tensor l2_loss(const at::Tensor& rendered, const at::Tensor& target) {
  check_shape(rendered, {-1, 3, -1, -1}, "l2_loss: rendered", "(V,3,H,W)");
  FLAT_CHECK(target.sizes() == rendered.sizes(),
             "l2_loss: target " + shape_str(target) + " does not match rendered " + shape_str(rendered));
  return (rendered - target.to(rendered.dtype())).square().mean();
}

}  // namespace flat::loss
