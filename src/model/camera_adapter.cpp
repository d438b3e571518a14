#include "flat/model/camera_adapter.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::model {

CameraAdapterImpl::CameraAdapterImpl(int64_t camera_channels, int64_t latent_channels, int64_t zero_kernel,
                                     bool zero_init, const KernelChoices& kernels) {
  FLAT_CHECK(zero_kernel == 1 || zero_kernel == 3, "CameraAdapter: zero_kernel must be 1 or 3, got " +
                                                       std::to_string(zero_kernel));
  conv = register_module("conv", CausalConv3d(camera_channels, latent_channels, Int3{3, 3, 3}, Int3{1, 1, 1},
                                              Int3{1, 1, 1}, kernels.conv_backend));
  const int64_t p = zero_kernel / 2;
  zero_conv = register_module("zero_conv", CausalConv3d(latent_channels, latent_channels,
                                                        Int3{zero_kernel, zero_kernel, zero_kernel}, Int3{1, 1, 1},
                                                        Int3{p, p, p}, kernels.conv_backend));
  if (zero_init) zero_conv->reset_parameters(/*zero=*/true);
}

at::Tensor CameraAdapterImpl::forward(const at::Tensor& camera_latents, StreamCache* cache) {
  FLAT_CHECK(camera_latents.dim() == 5 && camera_latents.size(1) == conv->in_channels(),
             "CameraAdapter: expected camera latents (B," + std::to_string(conv->in_channels()) + ",T',h,w), got " +
                 shape_str(camera_latents));
  at::Tensor h = cache ? conv->forward_cached(camera_latents, cache->next()) : conv->forward(camera_latents);
  h = at::silu(h);
  return cache ? zero_conv->forward_cached(h, cache->next()) : zero_conv->forward(h);
}

}  // namespace flat::model
