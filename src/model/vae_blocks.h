// The parts Encoder3d and Decoder3d of the Wan 2.1 VAE build alike, registered
// under the names the checkpoints use (../shared/docs/wan_vae.md): `middle`
// (residual block, attention, residual block), `head` (RMS_norm, SiLU,
// CausalConv3d) and the entries of a stage list (`downsamples`, `upsamples`).
#pragma once
#include <cstdint>
#include <vector>

#include <torch/nn/module.h>

#include "flat/model/attention_block.h"
#include "flat/model/causal_conv3d.h"
#include "flat/model/kernel_choices.h"
#include "flat/model/resample.h"
#include "flat/model/residual_block.h"
#include "flat/model/rms_norm.h"

namespace flat::model {

// `middle` on `parent`, all at `dim` channels: middle.0 (res1), .1 (attn), .2 (res2).
void add_middle(torch::nn::Module& parent, int64_t dim, const KernelChoices& kernels, ResidualBlock& res1,
                AttentionBlock& attn, ResidualBlock& res2);

// `head` on `parent`: head.0 the norm of `in` channels, head.2 the 3x3x3 conv
// to `out` channels (head.1, the SiLU, has no weights).
void add_head(torch::nn::Module& parent, int64_t in, int64_t out, const KernelChoices& kernels, RMSNorm& norm,
              CausalConv3d& conv);

// The next entry of a stage list: registered on `list` under its index,
// kept in `blocks` and its kind appended to `kinds` (0 residual block, 1
// resample: the forward walks the list by them).
void append_block(torch::nn::Module& list, const ResidualBlock& block, std::vector<ResidualBlock>& blocks,
                  std::vector<int>& kinds);
void append_block(torch::nn::Module& list, const Resample& block, std::vector<Resample>& blocks,
                  std::vector<int>& kinds);

}  // namespace flat::model
