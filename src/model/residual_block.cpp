#include "flat/model/residual_block.h"

#include <torch/torch.h>

namespace flat::model {

at::Tensor norm_silu_conv(const at::Tensor& x, RMSNorm& norm, CausalConv3d& conv, StreamCache* cache,
                          const at::Tensor& residual) {
  // The norm + SiLU writes straight into the causally padded input of the
  // conv; in streaming mode the padding is the layer's history instead of zeros.
  const int64_t n = conv->past_frames();
  if (cache == nullptr && x.size(2) == 1 && conv->has_single_frame_path())
    return conv->forward_single_frame(norm->silu_padded(x, 0), residual);
  if (cache == nullptr) return conv->forward_prepadded(norm->silu_padded(x, n), residual);
  return conv->forward_prepadded(norm->silu_streamed(x, n, cache->next()), residual);
}

ResidualBlockImpl::ResidualBlockImpl(int64_t in_channels, int64_t out_channels, const KernelChoices& kernels) {
  auto residual = register_module("residual", std::make_shared<torch::nn::Module>());
  const std::string& backend = kernels.conv_backend;
  norm1 = RMSNorm(in_channels, /*images=*/false, kernels.fused_norm);
  conv1 = CausalConv3d(in_channels, out_channels, Int3{3, 3, 3}, Int3{1, 1, 1}, Int3{1, 1, 1}, backend);
  norm2 = RMSNorm(out_channels, /*images=*/false, kernels.fused_norm);
  conv2 = CausalConv3d(out_channels, out_channels, Int3{3, 3, 3}, Int3{1, 1, 1}, Int3{1, 1, 1}, backend);
  residual->register_module("0", norm1);
  residual->register_module("2", conv1);
  residual->register_module("3", norm2);
  residual->register_module("6", conv2);
  if (in_channels != out_channels) {
    shortcut = register_module("shortcut", CausalConv3d(in_channels, out_channels, Int3{1, 1, 1}, Int3{1, 1, 1},
                                                        Int3{0, 0, 0}, backend));
  }
}

at::Tensor ResidualBlockImpl::forward(const at::Tensor& x, StreamCache* cache) {
  const at::Tensor h = norm_silu_conv(x, norm1, conv1, cache);
  // Dropout(0) is the identity; the skip is added by the second conv (in its
  // epilogue on the CUTLASS path: one pass over memory fewer).
  const at::Tensor skip = shortcut ? shortcut->forward(x) : x;
  return norm_silu_conv(h, norm2, conv2, cache, skip);
}

}  // namespace flat::model
