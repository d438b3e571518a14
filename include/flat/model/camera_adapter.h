// Camera adapter of the FLAT scene decoder (paper: Camera Conditioning; appendix
// table, "Plucker Adapter"): camera latents (B,32,T',h,w) = [E_ref; E_dir] ->
// CausalConv3d(32, 16, 3x3x3) -> SiLU -> zero-initialised CausalConv3d(16, 16)
// -> added to the video latent. At initialisation the output is exactly zero,
// so the pretrained decoder is undisturbed. Children "conv" and "zero_conv".
// Its input comes from the RPPC map (camera/ray_embeddings.h) encoded by
// model/camera_latents.h.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>
#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "flat/model/causal_conv3d.h"
#include "flat/model/kernel_choices.h"
#include "flat/model/stream_cache.h"

namespace flat::model {

class CameraAdapterImpl : public torch::nn::Module {
 public:
  // zero_kernel: 3 (3x3x3 zero conv) or 1 (1x1x1). zero_init false keeps the
  // conv's default (random) initialisation: the ablation "without zero-init".
  CameraAdapterImpl(int64_t camera_channels, int64_t latent_channels, int64_t zero_kernel, bool zero_init = true,
                    const KernelChoices& kernels = {});
  // (B,32,T',h,w) -> (B,16,T',h,w), the term added to the latent.
  at::Tensor forward(const at::Tensor& camera_latents, StreamCache* cache = nullptr);

  CausalConv3d conv{nullptr}, zero_conv{nullptr};
};
TORCH_MODULE(CameraAdapter);

}  // namespace flat::model
