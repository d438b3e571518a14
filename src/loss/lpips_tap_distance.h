// One LPIPS tap's part of the distance, from the raw (ReLU) features of the
// two image batches (paper, Losses: the perceptual term; docs/losses.md):
//   d_v = sum_c w_c mean_hw (a_c / (|a| + 1e-10) - b_c / (|b| + 1e-10))^2
// where |.| is the norm over channels at each pixel.
#pragma once
#include <ATen/ATen.h>

namespace flat::loss {

// fa, fb: (V,C,H,W) features, w: the lin layer's C weights. Returns (V), fp32
// (fp64 for fp64 features). Bf16 channels-last CUDA features take the fused
// kernels (forward and backward, loss/cuda/lpips_tap.cu); anything else the
// ATen ops, in fp32 at least. Differentiable in fa and fb (not w: LPIPS is a
// fixed metric).
at::Tensor lpips_tap_distance(const at::Tensor& fa, const at::Tensor& fb, const at::Tensor& w);

// Whether lpips_tap_distance runs the fused kernels for these features.
bool lpips_tap_fused(const at::Tensor& fa, const at::Tensor& fb);

}  // namespace flat::loss
