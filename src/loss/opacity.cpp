#include "flat/loss/opacity.h"

#include "flat/core/error.h"

namespace flat::loss {

at::Tensor opacity_loss(const at::Tensor& opacities) {
  FLAT_CHECK(opacities.defined() && opacities.numel() > 0, "opacity_loss: opacities are empty");
  return opacities.abs().mean();
}

}  // namespace flat::loss
