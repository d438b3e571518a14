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

at::Tensor lpips(loss::Lpips& net, const at::Tensor& rendered, const at::Tensor& target, int64_t max_size,
                 int64_t chunk) {
  torch::NoGradGuard no_grad;
  return loss::lpips_distance(net, rendered, target, max_size, chunk);
}

}  // namespace flat::eval
