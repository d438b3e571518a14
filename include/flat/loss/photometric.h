// Photometric L2 (paper, Losses: "pixel-wise L2 loss ... between the rendered
// and target frames"): the mean squared error over every pixel and channel.
#pragma once
#include <ATen/ATen.h>

namespace flat::loss {

// rendered, target: (V,3,H,W) in [0,1]. Returns a scalar.
at::Tensor l2_loss(const at::Tensor& rendered, const at::Tensor& target);

}  // namespace flat::loss
