// Image quality metrics of the paper's tables: PSNR, SSIM, LPIPS (per image).
// SSIM and LPIPS are computed by src/loss (one implementation, shared with
// training); this header is the evaluation-facing name for them.
#pragma once
#include <string>

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

// The two SSIM conventions that published tables use; same window (Gaussian
// 11x11, sigma 1.5), constants and population covariance, different borders:
//   skimage: scikit-image's structural_similarity (Wang et al.): statistics
//            only where the window fits inside the image, mean of that map.
//            Ours (ssim() above) and the default of flat_eval.
//   3dgs:    the ssim() of the 3DGS / 2DGS repositories: zero padding of 5
//            pixels, mean over every pixel (dark borders pull it down).
enum class SsimConvention { skimage, gaussian_zero_pad };
SsimConvention parse_ssim_convention(const std::string& name);  // "skimage" | "3dgs"
std::string ssim_convention_name(SsimConvention c);
at::Tensor ssim(const at::Tensor& rendered, const at::Tensor& target, SsimConvention convention,
                double data_range = 1.0);

// LPIPS (VGG) per image (V), without gradient, in chunks, no resizing unless
// max_size > 0.
at::Tensor lpips(loss::Lpips& net, const at::Tensor& rendered, const at::Tensor& target, int64_t max_size = 0,
                 int64_t chunk = 8);

}  // namespace flat::eval
