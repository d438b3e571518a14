#include "model/vae_blocks.h"

#include <string>

namespace flat::model {

void add_middle(torch::nn::Module& parent, int64_t dim, const KernelChoices& kernels, ResidualBlock& res1,
                AttentionBlock& attn, ResidualBlock& res2) {
  auto middle = parent.register_module("middle", std::make_shared<torch::nn::Module>());
  res1 = middle->register_module("0", ResidualBlock(dim, dim, kernels));
  attn = middle->register_module("1", AttentionBlock(dim, kernels));
  res2 = middle->register_module("2", ResidualBlock(dim, dim, kernels));
}

void add_head(torch::nn::Module& parent, int64_t in, int64_t out, const KernelChoices& kernels, RMSNorm& norm,
              CausalConv3d& conv) {
  auto head = parent.register_module("head", std::make_shared<torch::nn::Module>());
  norm = head->register_module("0", RMSNorm(in, /*images=*/false, kernels.fused_norm));
  conv = head->register_module(
      "2", CausalConv3d(in, out, Int3{3, 3, 3}, Int3{1, 1, 1}, Int3{1, 1, 1}, kernels.conv_backend));
}

void append_block(torch::nn::Module& list, const ResidualBlock& block, std::vector<ResidualBlock>& blocks,
                  std::vector<int>& kinds) {
  list.register_module(std::to_string(kinds.size()), block);
  blocks.push_back(block);
  kinds.push_back(0);
}

void append_block(torch::nn::Module& list, const Resample& block, std::vector<Resample>& blocks,
                  std::vector<int>& kinds) {
  list.register_module(std::to_string(kinds.size()), block);
  blocks.push_back(block);
  kinds.push_back(1);
}

}  // namespace flat::model
