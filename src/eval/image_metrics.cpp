#include "flat/eval/image_metrics.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::eval {

at::Tensor psnr(const at::Tensor& rendered, const at::Tensor& target, double data_range) {
  FLAT_CHECK(rendered.dim() == 4, "psnr: expected (V,C,H,W) images, got " + shape_str(rendered));
  FLAT_CHECK(rendered.sizes() == target.sizes(),
             "psnr: image shapes differ: " + shape_str(rendered) + " vs " + shape_str(target));
  auto mse = (rendered - target.to(rendered.dtype())).square().mean({1, 2, 3});
  return 10.0 * at::log10(data_range * data_range / mse);
}

SsimConvention parse_ssim_convention(const std::string& name) {
  if (name == "skimage") return SsimConvention::skimage;
  if (name == "3dgs") return SsimConvention::gaussian_zero_pad;
  fail("SSIM convention: expected skimage or 3dgs, got '" + name + "'");
}

std::string ssim_convention_name(SsimConvention c) {
  return c == SsimConvention::skimage ? "skimage" : "3dgs";
}

at::Tensor ssim(const at::Tensor& rendered, const at::Tensor& target, SsimConvention convention, double data_range) {
  if (convention == SsimConvention::skimage) return loss::ssim(rendered, target, data_range);
  // Padding the images by 5 zeros and filtering 'valid' is filtering 'same'
  // with zero padding, as the 3DGS code's conv2d(padding=5) does.
  FLAT_CHECK(rendered.dim() == 4, "ssim: expected (V,C,H,W) images, got " + shape_str(rendered));
  auto a = at::constant_pad_nd(rendered, {5, 5, 5, 5}, 0.0);
  auto b = at::constant_pad_nd(target.to(rendered.dtype()), {5, 5, 5, 5}, 0.0);
  return loss::ssim_map(a, b, data_range).mean({1, 2, 3});
}

at::Tensor lpips(loss::Lpips& net, const at::Tensor& rendered, const at::Tensor& target, int64_t max_size,
                 int64_t chunk) {
  torch::NoGradGuard no_grad;
  return loss::lpips_distance(net, rendered, target, {.max_size = max_size, .chunk = chunk});
}

}  // namespace flat::eval
