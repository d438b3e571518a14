// AttentionBlock(C) of the Wan VAE (../shared/docs/wan_vae.md): per frame, RMS_norm
// (images form) -> 1x1 conv to_qkv (C -> 3C) -> single-head attention over the
// H*W tokens (head dim C, scale 1/sqrt(C), SDPA) -> 1x1 conv proj -> + input.
// Children "norm", "to_qkv", "proj" as in the checkpoint.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>
#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "flat/model/kernel_choices.h"
#include "flat/model/rms_norm.h"

namespace flat::model {

// A 1x1 Conv2d's parameters (weight (out,in,1,1), bias (out)) applied as a
// matmul over channels-last tokens.
class PointwiseConv2dImpl : public torch::nn::Module {
 public:
  PointwiseConv2dImpl(int64_t in_channels, int64_t out_channels);
  // tokens (..., in) -> (..., out)
  at::Tensor forward(const at::Tensor& tokens);
  at::Tensor weight, bias;
};
TORCH_MODULE(PointwiseConv2d);

class AttentionBlockImpl : public torch::nn::Module {
 public:
  // kernels: its norm keeps fused_norm like every other (the attention's
  // norm has no SiLU, so it always runs as ATen ops).
  explicit AttentionBlockImpl(int64_t channels, const KernelChoices& kernels = {});
  // x (B,C,T,H,W) -> same shape. Frames are independent: no streaming state.
  at::Tensor forward(const at::Tensor& x);

  RMSNorm norm{nullptr};
  PointwiseConv2d to_qkv{nullptr}, proj{nullptr};
};
TORCH_MODULE(AttentionBlock);

}  // namespace flat::model
