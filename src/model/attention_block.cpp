#include "flat/model/attention_block.h"

#include <cmath>

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::model {

PointwiseConv2dImpl::PointwiseConv2dImpl(int64_t in_channels, int64_t out_channels) {
  const double bound = 1.0 / std::sqrt(double(in_channels));
  weight = register_parameter("weight", torch::empty({out_channels, in_channels, 1, 1}).uniform_(-bound, bound));
  bias = register_parameter("bias", torch::empty({out_channels}).uniform_(-bound, bound));
}

at::Tensor PointwiseConv2dImpl::forward(const at::Tensor& tokens) {
  return at::linear(tokens, weight.view({weight.size(0), weight.size(1)}), bias);
}

AttentionBlockImpl::AttentionBlockImpl(int64_t channels, const KernelChoices& kernels) {
  norm = register_module("norm", RMSNorm(channels, /*images=*/true, kernels.fused_norm));
  to_qkv = register_module("to_qkv", PointwiseConv2d(channels, 3 * channels));
  proj = register_module("proj", PointwiseConv2d(channels, channels));
}

at::Tensor AttentionBlockImpl::forward(const at::Tensor& x) {
  FLAT_CHECK(x.dim() == 5 && x.size(1) == norm->channels(),
             "AttentionBlock: expected (B," + std::to_string(norm->channels()) + ",T,H,W), got " + shape_str(x));
  const int64_t B = x.size(0), C = x.size(1), T = x.size(2), H = x.size(3), W = x.size(4);
  // Tokens (B*T, H*W, C): free when x is channels-last 3D, one copy otherwise.
  at::Tensor tokens = x.permute({0, 2, 3, 4, 1}).reshape({B * T, H * W, C});
  at::Tensor normed = rms_norm(tokens.transpose(1, 2), norm->gamma).transpose(1, 2);
  at::Tensor qkv = to_qkv->forward(normed).unsqueeze(1);  // (BT,1,HW,3C)
  at::Tensor q = qkv.narrow(3, 0, C), k = qkv.narrow(3, C, C), v = qkv.narrow(3, 2 * C, C);
  at::Tensor attn = at::scaled_dot_product_attention(q, k, v);  // scale 1/sqrt(C) by default
  at::Tensor out = proj->forward(attn.squeeze(1));              // (BT,HW,C)
  out = out.view({B, T, H, W, C}).permute({0, 4, 1, 2, 3});     // (B,C,T,H,W), channels-last strides
  return out + x;
}

}  // namespace flat::model
