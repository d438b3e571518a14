// Output heads of the FLAT scene decoder (paper appendix table, "Output Head":
// RMSNorm + SiLU + 3x3x3 CausalConv, "Independent or Monolithic head").
// Raw, pre-activation triangle parameters per output token (one token per 2x2
// pixel block per frame); the maths that turns them into world-space triangles
// lives in src/primitives.
//
// Channel map (colour_channels = 3):
//   ch  0      depth          ray depth D (centre = r_o + D r_d after activation)
//   ch  1..3   cholesky       L00, L10, L11 of the 2x2 lower-triangular shape matrix
//                             (diagonal made positive by the activation)
//   ch  4..5   tilt           two residual tilt angles of the ray-tangent frame
//   ch  6      spin           in-plane spin angle
//   ch  7..9   colour         RGB (colour_channels values)
//   ch 10      opacity        pre-sigmoid
//   ch 11      sigma          window sharpness, pre-activation
// Independent: one head (own RMS_norm gamma and conv) per group depth,
// cholesky, rotation (tilt + spin), colour, opacity, sigma; keys
// "heads.<group>.0.gamma", "heads.<group>.2.{weight,bias}". Monolithic: one head
// "heads.all" with every channel.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "flat/model/causal_conv3d.h"
#include "flat/model/rms_norm.h"
#include "flat/model/stream_cache.h"

namespace flat::model {

struct ChannelRange {
  int64_t start = 0;
  int64_t count = 0;
  at::Tensor of(const at::Tensor& out) const { return out.narrow(1, start, count); }  // (B,count,T,H,W)
};

struct TriangleChannels {
  ChannelRange depth, cholesky, tilt, spin, colour, opacity, sigma;
  int64_t total = 0;
  static TriangleChannels make(int64_t colour_channels = 3);
  // Head groups of the independent mode, in channel order: name and range.
  std::vector<std::pair<std::string, ChannelRange>> groups() const;
};

class OutputHeadsImpl : public torch::nn::Module {
 public:
  // mode: "independent" or "monolithic".
  OutputHeadsImpl(int64_t in_channels, const TriangleChannels& channels, const std::string& mode);
  // features (B,96,T,H,W) -> raw parameters (B,total,T,H,W).
  at::Tensor forward(const at::Tensor& features, StreamCache* cache = nullptr);

  const TriangleChannels& channels() const { return channels_; }
  std::vector<RMSNorm> norms;
  std::vector<CausalConv3d> convs;

 private:
  TriangleChannels channels_;
};
TORCH_MODULE(OutputHeads);

}  // namespace flat::model
