// Opacity regulariser (paper, Losses: used in the high-resolution stage, "as
// commonly used in feedforward 3D Gaussian methods"): L_O = mean_n |o_n|, an L1
// pull towards transparency so that unneeded triangles can be pruned (< 0.4).
#pragma once
#include <ATen/ATen.h>

namespace flat::loss {

// opacities: any shape (N), (B,N). Returns a scalar.
at::Tensor opacity_loss(const at::Tensor& opacities);

}  // namespace flat::loss
