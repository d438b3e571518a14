#include "flat/model/output_heads.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/model/residual_block.h"

namespace flat::model {

std::vector<std::pair<std::string, ChannelRange>> head_groups(const primitives::HeadChannels& c) {
  std::vector<std::pair<std::string, ChannelRange>> groups = {{"depth", ChannelRange{c.depth, 1}},
                                                              {c.shape_name, ChannelRange{c.shape, c.shape_count}},
                                                              {"rotation", ChannelRange{c.rotation, c.rotation_count}},
                                                              {"colour", ChannelRange{c.colour, c.colour_count}},
                                                              {"opacity", ChannelRange{c.opacity, 1}}};
  if (c.sigma >= 0) groups.push_back({"sigma", ChannelRange{c.sigma, 1}});  // the Gaussian layouts have none
  return groups;
}

OutputHeadsImpl::OutputHeadsImpl(int64_t in_channels, const primitives::HeadChannels& layout,
                                 const std::string& mode, const KernelChoices& kernels)
    : channels_(layout) {
  std::vector<std::pair<std::string, ChannelRange>> heads;
  if (mode == "independent") {
    heads = head_groups(layout);
  } else if (mode == "monolithic") {
    heads = {{"all", ChannelRange{0, layout.total}}};
  } else {
    fail("OutputHeads: mode must be 'independent' or 'monolithic', got '" + mode + "'");
  }
  for (const auto& [name, range] : heads) {
    auto head = register_module(name, std::make_shared<torch::nn::Module>());
    RMSNorm norm(in_channels, /*images=*/false, kernels.fused_norm);
    CausalConv3d conv(in_channels, range.count, Int3{3, 3, 3}, Int3{1, 1, 1}, Int3{1, 1, 1}, kernels.conv_backend);
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
