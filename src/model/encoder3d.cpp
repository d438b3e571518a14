#include "flat/model/encoder3d.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "model/vae_blocks.h"

namespace flat::model {

Encoder3dImpl::Encoder3dImpl(const WanVAEConfig& config, const KernelChoices& kernels) {
  config.check();
  const std::string& backend = kernels.conv_backend;
  // dims = dim * [1] + dim_mult: [96, 96, 192, 384, 384] for the pretrained model.
  std::vector<int64_t> dims{config.dim};
  for (int64_t m : config.dim_mult) dims.push_back(config.dim * m);

  conv1 = register_module("conv1", CausalConv3d(3, dims[0], Int3{3, 3, 3}, Int3{1, 1, 1}, Int3{1, 1, 1}, backend));
  auto downsamples = register_module("downsamples", std::make_shared<torch::nn::Module>());
  const size_t stages = config.dim_mult.size();
  for (size_t i = 0; i < stages; ++i) {
    int64_t in = dims[i];
    const int64_t out = dims[i + 1];
    for (int64_t r = 0; r < config.num_res_blocks; ++r) {
      append_block(*downsamples, ResidualBlock(in, out, kernels), down_res, down_kind);
      in = out;
    }
    if (i + 1 != stages) {
      const ResampleMode mode = config.temporal_downsample[i] ? ResampleMode::downsample3d : ResampleMode::downsample2d;
      append_block(*downsamples, Resample(out, mode, kernels), down_resample, down_kind);
    }
  }
  add_middle(*this, dims.back(), kernels, mid1, mid_attn, mid2);
  add_head(*this, dims.back(), 2 * config.z_dim, kernels, head_norm, head_conv);
}

at::Tensor Encoder3dImpl::forward(const at::Tensor& x, StreamCache* cache) {
  FLAT_CHECK(x.dim() == 5 && x.size(1) == 3, "Encoder3d: expected video (B,3,F,H,W), got " + shape_str(x));
  at::Tensor h = cache ? conv1->forward_cached(x, cache->next()) : conv1->forward(x);
  size_t r = 0, s = 0;
  for (int kind : down_kind) {
    h = kind == 0 ? down_res[r++]->forward(h, cache) : down_resample[s++]->forward(h, cache);
  }
  h = mid1->forward(h, cache);
  h = mid_attn->forward(h);
  h = mid2->forward(h, cache);
  return norm_silu_conv(h, head_norm, head_conv, cache);
}

}  // namespace flat::model
