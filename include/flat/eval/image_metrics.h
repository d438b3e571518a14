// Image quality metrics of the paper's tables: PSNR, SSIM, LPIPS (per image).
// SSIM and LPIPS are computed by src/loss (one implementation, shared with
// training); this header is the evaluation-facing name for them.
#pragma once
#include <ATen/ATen.h>

#include "flat/loss/lpips.h"
#include "flat/loss/ssim.h"

namespace flat::eval {

// PSNR per image (V) of (V,C,H,W) images with values in [0, data_range]:
// 10 log10(data_range^2 / MSE), MSE over channels and pixels. Identical images
// give +inf.
at::Tensor psnr(const at::Tensor& rendered, const at::Tensor& target, double data_range = 1.0);

// SSIM per image (V): 11x11 Gaussian window, sigma 1.5, standard constants.
inline at::Tensor ssim(const at::Tensor& rendered, const at::Tensor& target, double data_range = 1.0) {
  return loss::ssim(rendered, target, data_range);
}

// LPIPS (VGG) per image (V), without gradient, in chunks, no resizing unless
// max_size > 0.
at::Tensor lpips(loss::Lpips& net, const at::Tensor& rendered, const at::Tensor& target, int64_t max_size = 0,
                 int64_t chunk = 8);

}  // namespace flat::eval
