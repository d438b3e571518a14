#include "flat/model/decoder3d.h"

#include "flat/model/activation_checkpoint.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/model/encoder3d.h"
#include "model/vae_blocks.h"

namespace flat::model {

Decoder3dImpl::Decoder3dImpl(const WanVAEConfig& config, bool scene_variant, const KernelChoices& kernels)
    : scene_variant_(scene_variant) {
  config.check();
  const std::string& backend = kernels.conv_backend;
  // dims = dim * [mult[-1]] + reversed(mult): [384, 384, 384, 192, 96] for the pretrained model.
  std::vector<int64_t> dims{config.dim * config.dim_mult.back()};
  for (auto it = config.dim_mult.rbegin(); it != config.dim_mult.rend(); ++it) dims.push_back(config.dim * *it);
  std::vector<int64_t> temporal_upsample(config.temporal_downsample.rbegin(), config.temporal_downsample.rend());

  conv1 = register_module("conv1",
                          CausalConv3d(config.z_dim, dims[0], Int3{3, 3, 3}, Int3{1, 1, 1}, Int3{1, 1, 1}, backend));
  add_middle(*this, dims[0], kernels, mid1, mid_attn, mid2);

  auto upsamples = register_module("upsamples", std::make_shared<torch::nn::Module>());
  const size_t stages = config.dim_mult.size();
  for (size_t i = 0; i < stages; ++i) {
    // After an upsampling stage the width is halved by the Resample's Conv2d.
    int64_t in = (i == 0) ? dims[i] : dims[i] / 2;
    const int64_t out = dims[i + 1];
    for (int64_t r = 0; r < config.num_res_blocks + 1; ++r) {
      append_block(*upsamples, ResidualBlock(in, out, kernels), up_res, up_kind);
      in = out;
    }
    if (i + 1 != stages) {
      ResampleMode mode = temporal_upsample[i] ? ResampleMode::upsample3d : ResampleMode::upsample2d;
      // FLAT: the last x2 spatial upsample becomes the identity; its conv stays.
      if (scene_variant && i + 2 == stages) {
        FLAT_CHECK(mode == ResampleMode::upsample2d, "Decoder3d: the scene variant expects a spatial-only last upsample");
        mode = ResampleMode::conv_only;
      }
      append_block(*upsamples, Resample(out, mode, kernels), up_resample, up_kind);
    }
  }
  out_features_ = dims.back();
  if (!scene_variant) add_head(*this, out_features_, 3, kernels, head_norm, head_conv);
}

at::Tensor Decoder3dImpl::forward(const at::Tensor& z, StreamCache* cache) {
  return forward_tail(forward_trunk(z, cache, up_kind.size()), cache, up_kind.size());  // (a temporary: moved)
}

at::Tensor Decoder3dImpl::forward_trunk(const at::Tensor& z, StreamCache* cache, size_t end) {
  FLAT_CHECK(z.dim() == 5 && z.size(1) == conv1->in_channels(),
             "Decoder3d: expected latent (B," + std::to_string(conv1->in_channels()) + ",T,h,w), got " + shape_str(z));
  at::Tensor h = cache ? conv1->forward_cached(z, cache->next()) : conv1->forward(z);
  h = run_block([this, cache](const at::Tensor& x) { return mid1->forward(x, cache); }, h, cache);
  h = run_block([this](const at::Tensor& x) { return mid_attn->forward(x); }, h, cache);
  h = run_block([this, cache](const at::Tensor& x) { return mid2->forward(x, cache); }, h, cache);
  return forward_upsamples(h, cache, 0, end);
}

at::Tensor Decoder3dImpl::forward_tail(at::Tensor h, StreamCache* cache, size_t begin) {
  at::Tensor out = forward_upsamples(std::move(h), cache, begin, up_kind.size());  // h freed as the stages run
  if (scene_variant_) return out;
  return norm_silu_conv(out, head_norm, head_conv, cache);
}

at::Tensor Decoder3dImpl::forward_upsamples(at::Tensor h, StreamCache* cache, size_t begin, size_t end) {
  size_t r = 0, s = 0;  // residual blocks and resamples before stage `begin`
  for (size_t i = 0; i < begin; ++i) (up_kind[i] == 0 ? r : s)++;
  for (size_t i = begin; i < end; ++i) {
    if (up_kind[i] == 0) {
      ResidualBlockImpl* block = up_res[r++].get();
      h = run_block([block, cache](const at::Tensor& x) { return block->forward(x, cache); }, h, cache);
    } else {
      ResampleImpl* block = up_resample[s++].get();
      h = run_block([block, cache](const at::Tensor& x) { return block->forward(x, cache); }, h, cache);
    }
  }
  return h;
}

at::Tensor Decoder3dImpl::run_block(const std::function<at::Tensor(const at::Tensor&)>& block, const at::Tensor& h,
                                    StreamCache* cache) const {
  // Streaming caches are filled by the forward: a recomputation would fill them twice.
  if (!checkpoint_blocks_ || cache) return block(h);
  return checkpointed(block, h);
}

size_t Decoder3dImpl::trunk_stages() const {
  size_t s = 0;
  for (size_t i = 0; i < up_kind.size(); ++i) {
    if (up_kind[i] == 1 && up_resample[s++]->mode() == ResampleMode::upsample3d) return i + 1;
  }
  return 0;
}

}  // namespace flat::model
