// CausalConv3d of the Wan 2.1 VAE (../shared/docs/wan_vae.md, Building blocks): a Conv3d
// whose temporal padding is causal, 2*pt zero frames in the past and none in the
// future, and whose spatial padding is symmetric. Parameters `weight`
// (out,in,kt,kh,kw) and `bias` (out) keep the checkpoint's names.
#pragma once
#include <array>
#include <cstdint>
#include <string>

#include <ATen/ATen.h>
#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "flat/model/stream_cache.h"

namespace flat::model {

using Int3 = std::array<int64_t, 3>;

class CausalConv3dImpl : public torch::nn::Module {
 public:
  // conv_backend: which implementation runs its stride-1 convs without
  // autograd (conv3d_inference's backend, KernelChoices::conv_backend);
  // unknown names throw.
  CausalConv3dImpl(int64_t in_channels, int64_t out_channels, Int3 kernel, Int3 stride = {1, 1, 1},
                   Int3 padding = {0, 0, 0}, std::string conv_backend = "auto");

  // Full sequence: pads 2*pt zero frames in front (one copy), then the conv
  // (a single frame: forward_single_frame).
  at::Tensor forward(const at::Tensor& x);
  // Streaming: prepends this layer's history (zeros on the first chunk) instead
  // of the zero frames, and keeps the last 2*pt input frames as the new history.
  at::Tensor forward_cached(const at::Tensor& x, at::Tensor& history);
  // The conv alone, on an input that already carries its 2*pt past frames
  // (written there by the fused norm + SiLU, which saves the padding copy);
  // `residual`, when given, is added to the output (fused into the conv's
  // epilogue where conv3d_inference runs a CUTLASS kernel).
  at::Tensor forward_prepadded(const at::Tensor& x_padded, const at::Tensor& residual = {});
  // The full sequence of one frame (the VAE's single-frame stage): its past is
  // all zero frames, so only the kernel's last temporal tap meets data and the
  // conv runs with that tap alone, unpadded (kt times less work; the same
  // output and gradients up to rounding). Needs x with T = 1 and
  // has_single_frame_path().
  at::Tensor forward_single_frame(const at::Tensor& x, const at::Tensor& residual = {});
  bool has_single_frame_path() const { return past_frames() > 0 && stride_[0] == 1 && weight.size(2) == past_frames() + 1; }

  int64_t past_frames() const { return 2 * padding_[0]; }
  int64_t in_channels() const { return weight.size(1); }
  int64_t out_channels() const { return weight.size(0); }
  const std::string& conv_backend() const { return conv_backend_; }
  // Re-draws the parameters: zeros (for the adapter's zero conv) or PyTorch's
  // default conv init (uniform +-1/sqrt(fan_in)).
  void reset_parameters(bool zero = false);

  at::Tensor weight, bias;

 private:
  Int3 stride_, padding_;
  std::string conv_backend_;
};
TORCH_MODULE(CausalConv3d);

// x with n zero frames prepended along T (dim 2), in x's memory format.
at::Tensor pad_past_frames(const at::Tensor& x, int64_t n);

}  // namespace flat::model
