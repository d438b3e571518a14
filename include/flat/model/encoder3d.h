// Encoder3d of the Wan 2.1 VAE (../shared/docs/wan_vae.md, Encoder3d): conv1, the
// `downsamples` list (residual blocks and Resample), `middle` (Res, Attn, Res),
// `head` (RMS_norm, SiLU, CausalConv3d -> 2*z_dim). Video (B,3,1+4k,H,W) ->
// (B,2*z_dim,1+k,H/8,W/8) (before the VAE's 1x1x1 conv1).
#pragma once
#include <vector>

#include <ATen/ATen.h>
#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "flat/model/attention_block.h"
#include "flat/model/causal_conv3d.h"
#include "flat/model/kernel_choices.h"
#include "flat/model/resample.h"
#include "flat/model/residual_block.h"
#include "flat/model/rms_norm.h"
#include "flat/model/stream_cache.h"
#include "flat/model/wan_vae_config.h"

namespace flat::model {

class Encoder3dImpl : public torch::nn::Module {
 public:
  explicit Encoder3dImpl(const WanVAEConfig& config, const KernelChoices& kernels = {});
  // Full sequence (cache == nullptr) or one chunk (1 frame first, then 4).
  at::Tensor forward(const at::Tensor& x, StreamCache* cache = nullptr);

  CausalConv3d conv1{nullptr};
  // Each entry of `downsamples` is a residual block or a resample.
  std::vector<ResidualBlock> down_res;
  std::vector<Resample> down_resample;
  std::vector<int> down_kind;  // 0 = residual block (index into down_res), 1 = resample
  ResidualBlock mid1{nullptr}, mid2{nullptr};
  AttentionBlock mid_attn{nullptr};
  RMSNorm head_norm{nullptr};
  CausalConv3d head_conv{nullptr};
};
TORCH_MODULE(Encoder3d);

}  // namespace flat::model
