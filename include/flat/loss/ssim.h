// SSIM (Wang et al. 2004) as used for evaluation tables: 11x11 Gaussian
// window, sigma 1.5, C1 = (0.01 L)^2, C2 = (0.03 L)^2, data range L = 1,
// population (not sample) statistics, 'valid' filtering (no padding: the same
// numbers as scikit-image's structural_similarity(gaussian_weights=True,
// sigma=1.5, use_sample_covariance=False, data_range=1), which crops the
// padded border). Shared by the metric (src/eval) and any SSIM loss.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

namespace flat::loss {

// Normalised 1-D Gaussian taps (size odd): 0.0010284, 0.0075988, 0.0360008,
// 0.1093607, 0.2130055, 0.2660117 (centre), symmetric, for 11 and 1.5.
at::Tensor gaussian_window_1d(int64_t size = 11, double sigma = 1.5,
                              const at::TensorOptions& options = at::kFloat);

// Per-pixel SSIM map (V,C,H-10,W-10) of two (V,C,H,W) images, H, W >= 11.
at::Tensor ssim_map(const at::Tensor& a, const at::Tensor& b, double data_range = 1.0);

// Mean SSIM per image (V): the mean of ssim_map over channels and pixels.
at::Tensor ssim(const at::Tensor& a, const at::Tensor& b, double data_range = 1.0);

}  // namespace flat::loss
