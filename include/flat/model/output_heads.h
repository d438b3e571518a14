// Output heads of the FLAT scene decoder (paper appendix table, "Output Head":
// RMSNorm + SiLU + 3x3x3 CausalConv, "Independent or Monolithic head").
// Raw, pre-activation triangle parameters per output token (one token per 2x2
// pixel block per frame), in the channel layout of
// include/flat/primitives/head_channels.h (the one place that defines it;
// 12 channels for the paper's ray-centred RGB triangles); the maths that turns
// them into world-space triangles lives in src/primitives.
//
// Independent: one head (own RMS_norm gamma and conv) per group depth, shape
// ("cholesky" for the ray-centred and global-rotation layouts, "offsets" for
// three offsets, "scale" for the 3DGS / 2DGS layouts), rotation, colour, opacity,
// sigma (triangles only); keys
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
#include "flat/model/kernel_choices.h"
#include "flat/model/rms_norm.h"
#include "flat/model/stream_cache.h"
#include "flat/primitives/head_channels.h"

namespace flat::model {

struct ChannelRange {
  int64_t start = 0;
  int64_t count = 0;
  at::Tensor of(const at::Tensor& out) const { return out.narrow(1, start, count); }  // (B,count,T,H,W)
};

// Head groups of the independent mode, in channel order: name and range.
std::vector<std::pair<std::string, ChannelRange>> head_groups(const primitives::HeadChannels& layout);

class OutputHeadsImpl : public torch::nn::Module {
 public:
  // mode: "independent" or "monolithic".
  OutputHeadsImpl(int64_t in_channels, const primitives::HeadChannels& layout, const std::string& mode,
                  const KernelChoices& kernels = {});
  // features (B,96,T,H,W) -> raw parameters (B,total,T,H,W).
  at::Tensor forward(const at::Tensor& features, StreamCache* cache = nullptr);

  const primitives::HeadChannels& channels() const { return channels_; }
  std::vector<RMSNorm> norms;
  std::vector<CausalConv3d> convs;

 private:
  primitives::HeadChannels channels_;
};
TORCH_MODULE(OutputHeads);

}  // namespace flat::model
