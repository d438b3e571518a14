// ResidualBlock(in, out) of the Wan VAE (../shared/docs/wan_vae.md): residual =
// [0] RMS_norm(in), [1] SiLU, [2] CausalConv3d(in,out,3), [3] RMS_norm(out),
// [4] SiLU, [5] Dropout(0), [6] CausalConv3d(out,out,3); shortcut =
// CausalConv3d(in,out,1) when in != out. Children are named "residual.{0,2,3,6}"
// and "shortcut" like the checkpoint.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>
#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "flat/model/causal_conv3d.h"
#include "flat/model/kernel_choices.h"
#include "flat/model/rms_norm.h"
#include "flat/model/stream_cache.h"

namespace flat::model {

class ResidualBlockImpl : public torch::nn::Module {
 public:
  // kernels: fused_norm for the norms, conv_backend for the convs.
  ResidualBlockImpl(int64_t in_channels, int64_t out_channels, const KernelChoices& kernels = {});
  // cache == nullptr: full sequence; else one streaming chunk.
  at::Tensor forward(const at::Tensor& x, StreamCache* cache = nullptr);

  RMSNorm norm1{nullptr}, norm2{nullptr};
  CausalConv3d conv1{nullptr}, conv2{nullptr}, shortcut{nullptr};
};
TORCH_MODULE(ResidualBlock);

// conv(silu(norm(x))) (+ residual): the unit of residual blocks and of the
// encoder's, decoder's and scene decoder's heads. cache == nullptr: full
// sequence (zero past frames); else one streaming chunk (the layer's history).
// The kernels are those norm and conv were built with.
at::Tensor norm_silu_conv(const at::Tensor& x, RMSNorm& norm, CausalConv3d& conv, StreamCache* cache,
                          const at::Tensor& residual = {});

}  // namespace flat::model
