#include "flat/model/output_heads.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/model/encoder3d.h"

namespace flat::model {

TriangleChannels TriangleChannels::make(int64_t colour_channels) {
  FLAT_CHECK(colour_channels > 0, "TriangleChannels: colour_channels must be positive");
  TriangleChannels c;
  int64_t next = 0;
  auto take = [&](int64_t n) { ChannelRange r{next, n}; next += n; return r; };
  c.depth = take(1);
  c.cholesky = take(3);
  c.tilt = take(2);
  c.spin = take(1);
  c.colour = take(colour_channels);
  c.opacity = take(1);
  c.sigma = take(1);
  c.total = next;
  return c;
}

std::vector<std::pair<std::string, ChannelRange>> TriangleChannels::groups() const {
  return {{"depth", depth},
          {"cholesky", cholesky},
          {"rotation", ChannelRange{tilt.start, tilt.count + spin.count}},
          {"colour", colour},
          {"opacity", opacity},
          {"sigma", sigma}};
}

OutputHeadsImpl::OutputHeadsImpl(int64_t in_channels, const TriangleChannels& channels, const std::string& mode)
    : channels_(channels) {
  std::vector<std::pair<std::string, ChannelRange>> heads;
  if (mode == "independent") {
    heads = channels.groups();
  } else if (mode == "monolithic") {
    heads = {{"all", ChannelRange{0, channels.total}}};
  } else {
    fail("OutputHeads: mode must be 'independent' or 'monolithic', got '" + mode + "'");
  }
  for (const auto& [name, range] : heads) {
    auto head = register_module(name, std::make_shared<torch::nn::Module>());
    RMSNorm norm(in_channels, /*images=*/false);
    CausalConv3d conv(in_channels, range.count, Int3{3, 3, 3}, Int3{1, 1, 1}, Int3{1, 1, 1});
    head->register_module("0", norm);
    head->register_module("2", conv);
    norms.push_back(norm);
    convs.push_back(conv);
  }
}

at::Tensor OutputHeadsImpl::forward(const at::Tensor& features, StreamCache* cache) {
  if (convs.size() == 1) return norm_silu_conv(features, norms[0], convs[0], cache);
  std::vector<at::Tensor> outs;
  for (size_t i = 0; i < convs.size(); ++i) outs.push_back(norm_silu_conv(features, norms[i], convs[i], cache));
  return at::cat(outs, 1);
}

}  // namespace flat::model
