// Resample of the Wan VAE (../shared/docs/wan_vae.md). Children as in the checkpoint:
// "resample.1" (the per-frame Conv2d) and "time_conv" (CausalConv3d).
//   upsample2d   : nearest x2, Conv2d(C, C/2, 3, pad 1), per frame
//   upsample3d   : time_conv (C -> 2C, (3,1,1)) doubles frames 1..T-1, then upsample2d
//   downsample2d : pad right/bottom 1, Conv2d(C, C, 3, stride 2), per frame
//   downsample3d : downsample2d, then time_conv (C -> C, (3,1,1), stride 2, no pad)
//   conv_only    : FLAT's scene decoder: upsample2d without the nearest x2
//                  (keeps the pretrained Conv2d C -> C/2, paper appendix table)
#pragma once
#include <cstdint>
#include <string>
#include <mutex>
#include <tuple>

#include <ATen/ATen.h>
#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "flat/model/causal_conv3d.h"
#include "flat/model/kernel_choices.h"
#include "flat/model/stream_cache.h"

namespace flat::model {

enum class ResampleMode { upsample2d, upsample3d, downsample2d, downsample3d, conv_only };

class ResampleImpl : public torch::nn::Module {
 public:
  // kernels: subpixel_upsample (the upsampling convs as one sub-pixel conv on
  // the low-resolution input: same result, 4/9 of the work; false: nearest x2
  // then the 3x3 conv, as the reference does) and conv_backend (its convs and
  // time_conv's).
  ResampleImpl(int64_t channels, ResampleMode mode, const KernelChoices& kernels = {});
  // Full sequence (cache == nullptr) or one streaming chunk.
  //  upsample3d full: frame 0 passes, frames 1.. are doubled: T -> 1 + 2(T-1).
  //  downsample3d full: frame 0 passes, then the stride-2 conv over all frames: 1+2k -> 1+k.
  at::Tensor forward(const at::Tensor& x, StreamCache* cache = nullptr);

  ResampleMode mode() const { return mode_; }
  bool subpixel_upsample() const { return subpixel_; }
  // The per-frame 2D conv, stored as Conv2d parameters (out,in,3,3).
  at::Tensor conv_weight, conv_bias;
  CausalConv3d time_conv{nullptr};

 private:
  ResampleMode mode_;
  bool subpixel_;
  std::string conv_backend_;
  at::Tensor spatial(const at::Tensor& x) const;  // the per-frame part
  void interleave_into(at::Tensor out, const at::Tensor& y) const;  // (B,2C,T,..) -> out (B,C,2T,..)
  // upsample3d's temporal half: [frame 0 if pass_first] + frames doubled by time_conv.
  at::Tensor upsample_time(const at::Tensor& x, bool pass_first, at::Tensor* history);
  // The sub-pixel phase filters built from conv_weight (inference only).
  struct SubpixelCache {
    std::tuple<void*, int64_t, int64_t, at::ScalarType, at::MemoryFormat> key;
    at::Tensor weight, bias;
    std::mutex mutex;  // modules may be shared by threads
  };
  mutable SubpixelCache subpixel_cache_;
};
TORCH_MODULE(Resample);

}  // namespace flat::model
