#include "flat/model/encoder3d.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::model {

Encoder3dImpl::Encoder3dImpl(const WanVAEConfig& config, const KernelChoices& kernels) {
  config.check();
  const std::string& backend = kernels.conv_backend;
  // dims = dim * [1] + dim_mult: [96, 96, 192, 384, 384] for the pretrained model.
  std::vector<int64_t> dims{config.dim};
  for (int64_t m : config.dim_mult) dims.push_back(config.dim * m);

  conv1 = register_module("conv1", CausalConv3d(3, dims[0], Int3{3, 3, 3}, Int3{1, 1, 1}, Int3{1, 1, 1}, backend));
  auto downsamples = register_module("downsamples", std::make_shared<torch::nn::Module>());
  int index = 0;
  const size_t stages = config.dim_mult.size();
  for (size_t i = 0; i < stages; ++i) {
    int64_t in = dims[i];
    const int64_t out = dims[i + 1];
    for (int64_t r = 0; r < config.num_res_blocks; ++r) {
      ResidualBlock block(in, out, kernels);
      downsamples->register_module(std::to_string(index++), block);
      down_res.push_back(block);
      down_kind.push_back(0);
      in = out;
    }
    if (i + 1 != stages) {
      Resample resample(out, config.temporal_downsample[i] ? ResampleMode::downsample3d : ResampleMode::downsample2d,
                        kernels);
      downsamples->register_module(std::to_string(index++), resample);
      down_resample.push_back(resample);
      down_kind.push_back(1);
    }
  }
  const int64_t top = dims.back();
  auto middle = register_module("middle", std::make_shared<torch::nn::Module>());
  mid1 = ResidualBlock(top, top, kernels);
  mid_attn = AttentionBlock(top, kernels);
  mid2 = ResidualBlock(top, top, kernels);
  middle->register_module("0", mid1);
  middle->register_module("1", mid_attn);
  middle->register_module("2", mid2);
  auto head = register_module("head", std::make_shared<torch::nn::Module>());
  head_norm = RMSNorm(top, /*images=*/false, kernels.fused_norm);
  head_conv = CausalConv3d(top, 2 * config.z_dim, Int3{3, 3, 3}, Int3{1, 1, 1}, Int3{1, 1, 1}, backend);
  head->register_module("0", head_norm);
  head->register_module("2", head_conv);
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
