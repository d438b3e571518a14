// Normal loss (paper, Losses):  L_N = sum_i M_i (1 - n_i . N_i) / sum_i M_i,
// M_i = 1 where alpha_i > 0.5 (and the target normal is valid, |N_i| > 0.5),
// n = rendered normal normalised to unit length (the rasterizer composites
// unit normals with alpha weights, so its output is shorter than 1 at partial
// coverage), N = pseudo-ground-truth normal. Both in camera space.
#pragma once
#include <ATen/ATen.h>

namespace flat::loss {

// rendered, target: (V,3,H,W); alpha: (V,1,H,W). Returns a scalar (0, still in
// the graph, when no pixel is valid).
at::Tensor normal_loss(const at::Tensor& rendered, const at::Tensor& target, const at::Tensor& alpha,
                       double alpha_threshold = 0.5);

}  // namespace flat::loss
