// Scale-and-shift-invariant disparity loss (paper, Losses: "as in MiDaS").
//
// Per image v, over its valid pixels M (mask true), the least-squares scale
// and shift that align the predicted disparity p to the target g,
//   (s, t) = argmin  sum_M (s p + t - g)^2,
//   [sum p^2  sum p] [s]   [sum p g]
//   [sum p    |M|  ] [t] = [sum g  ]        (sums over M),
// then the mean absolute error of the aligned prediction,
//   L_v = (1/|M|) sum_M |s p + t - g|,
// and the loss is the mean of L_v over images with at least two valid pixels
// (images with fewer contribute nothing; if no image has any, the loss is 0
// and still connected to the graph). When the prediction is constant over M
// the system is singular: then s = 0 and t = mean(g). s and t are functions of
// p, and gradients flow through them (as in MiDaS' closed-form alignment), so
// the loss is exactly invariant to any s' p + t' with s' > 0.
#pragma once
#include <ATen/ATen.h>

namespace flat::loss {

// pred_disparity, target_disparity: (V,1,H,W) or (V,H,W); mask: same shape, bool
// (undefined = every pixel valid). Returns a scalar.
at::Tensor disparity_loss(const at::Tensor& pred_disparity, const at::Tensor& target_disparity,
                          const at::Tensor& mask = {});

// 1 / max(depth, min_depth): disparity of a depth map (metres).
at::Tensor depth_to_disparity(const at::Tensor& depth, double min_depth = 1e-3);

}  // namespace flat::loss
