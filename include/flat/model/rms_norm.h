// RMS_norm of the Wan VAE: x / max(||x||_2 over channels, 1e-12) * sqrt(C) * gamma.
// gamma is (C,1,1,1) for video tensors and (C,1,1) inside the attention block
// ("images" form); no bias. The parameter keeps the checkpoint name `gamma`.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>
#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

namespace flat::model {

class RMSNormImpl : public torch::nn::Module {
 public:
  // fused: rms_norm_silu_padded / _streamed of this norm may use the fused
  // CUDA kernel (KernelChoices::fused_norm).
  RMSNormImpl(int64_t channels, bool images, bool fused = true);
  // Normalises over dim 1 of (B,C,...) tensors.
  at::Tensor forward(const at::Tensor& x);
  // rms_norm_silu_padded / rms_norm_silu_streamed with this norm's gamma and choice.
  at::Tensor silu_padded(const at::Tensor& x, int64_t n, const at::Tensor& history = {}) const;
  at::Tensor silu_streamed(const at::Tensor& x, int64_t n, at::Tensor& history) const;
  at::Tensor gamma;
  int64_t channels() const { return gamma.size(0); }
  bool fused() const { return fused_; }

 private:
  bool fused_;
};
TORCH_MODULE(RMSNorm);

// silu(rms_norm(x)) for x (B,C,T,H,W), returned as (B,C,n+T,H,W) whose first n
// frames are `history` ((B,C,n,H,W); zeros when undefined): the input of the
// next causal conv, built with no separate padding copy. On CUDA where
// `fused` allows it: without autograd one fused kernel (fused_norm_available);
// with autograd and no history, one autograd node with fused forward and
// backward kernels (x is made channels-last, and so is the result).
// Otherwise ATen ops (differentiable). Same result.
at::Tensor rms_norm_silu_padded(const at::Tensor& x, const at::Tensor& gamma, int64_t n,
                                const at::Tensor& history = {}, bool fused = true);

// rms_norm over dim 1 (no SiLU, no padding); gamma of any shape with C entries.
at::Tensor rms_norm(const at::Tensor& x, const at::Tensor& gamma);

// One streaming chunk: rms_norm_silu_padded(x, gamma, n, history), and
// `history` becomes the last n frames of the result (the next chunk's past).
at::Tensor rms_norm_silu_streamed(const at::Tensor& x, const at::Tensor& gamma, int64_t n, at::Tensor& history,
                                  bool fused = true);

// True when the fused CUDA kernels take x and gamma: a CUDA (B,C,T,H,W)
// tensor in fp32 or bf16 of any layout (it is made channels-last), C within
// the kernel's reach, gamma of any float dtype (cast to x's).
bool fused_norm_eligible(const at::Tensor& x, const at::Tensor& gamma);

// True when the fused forward kernel alone serves rms_norm_silu_padded for x
// (eligible and no autograd; it does when `fused` is true).
bool fused_norm_available(const at::Tensor& x, const at::Tensor& gamma);

}  // namespace flat::model
