// Decoder3d of the Wan 2.1 VAE (../shared/docs/wan_vae.md, Decoder3d): conv1, `middle`
// (Res, Attn, Res), `upsamples` (3 residual blocks per stage, then Resample),
// `head` (RMS_norm, SiLU, CausalConv3d -> 3). Latent (B,z_dim,T',h,w) ->
// (B,3,1+4(T'-1),8h,8w).
//
// The FLAT variant (`scene_variant`): the last Resample keeps its Conv2d but
// drops the nearest x2 (ResampleMode::conv_only) and there is no RGB head; the
// output is the 96-channel feature map at (1+4(T'-1), 4h, 4w) (paper appendix,
// Scene Decoder Architecture).
#pragma once
#include <functional>
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

class Decoder3dImpl : public torch::nn::Module {
 public:
  // kernels: the implementations its norms, convs and upsamples use.
  Decoder3dImpl(const WanVAEConfig& config, bool scene_variant = false, const KernelChoices& kernels = {});
  // Full sequence (cache == nullptr) or one latent frame with the caches.
  at::Tensor forward(const at::Tensor& z, StreamCache* cache = nullptr);
  // forward() in two parts: conv1, middle and the `upsamples` stages [0, end),
  // then the stages [begin, size) and (VAE) the RGB head; forward(z) ==
  // forward_tail(forward_trunk(z, c, k), c, k). With caches, the two parts
  // may be fed chunks of different lengths (each part keeps its own cache).
  at::Tensor forward_trunk(const at::Tensor& z, StreamCache* cache, size_t end);
  at::Tensor forward_tail(at::Tensor h, StreamCache* cache, size_t begin);
  // Stages up to and including the first temporal upsample (0 if none): the
  // low-resolution trunk, whose activations are small whatever its chunk length.
  size_t trunk_stages() const;
  // Frames the trunk (split = trunk_stages()) emits for latent frame `t`:
  // its temporal x2 passes frame 0 and doubles the others; 1 without one.
  static int64_t trunk_frames(int64_t t, size_t split) { return split > 0 && t > 0 ? 2 : 1; }

  // Full-sequence forwards with gradients recompute each block (mid blocks,
  // residual blocks, resamples) in the backward instead of keeping its
  // activations (activation_checkpoint.h). Same outputs and gradients.
  void set_activation_checkpointing(bool on) { checkpoint_blocks_ = on; }
  bool activation_checkpointing() const { return checkpoint_blocks_; }

  bool scene_variant() const { return scene_variant_; }
  int64_t out_features() const { return out_features_; }  // channels before the head (dim)

  CausalConv3d conv1{nullptr};
  ResidualBlock mid1{nullptr}, mid2{nullptr};
  AttentionBlock mid_attn{nullptr};
  std::vector<ResidualBlock> up_res;
  std::vector<Resample> up_resample;
  std::vector<int> up_kind;  // 0 = residual block, 1 = resample, in `upsamples` order
  RMSNorm head_norm{nullptr};
  CausalConv3d head_conv{nullptr};

 private:
  at::Tensor forward_upsamples(at::Tensor h, StreamCache* cache, size_t begin, size_t end);
  // block(h), checkpointed when switched on and no stream cache is in use.
  at::Tensor run_block(const std::function<at::Tensor(const at::Tensor&)>& block, const at::Tensor& h,
                       StreamCache* cache) const;
  bool scene_variant_;
  bool checkpoint_blocks_ = false;
  int64_t out_features_ = 0;
};
TORCH_MODULE(Decoder3d);

}  // namespace flat::model
