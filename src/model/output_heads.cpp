#include "flat/model/output_heads.h"

#include <torch/torch.h>
#if FLAT_WITH_CUDA
#include <ATen/cuda/CUDAContext.h>
#include <ATen/cuda/CUDAEvent.h>
#include <c10/cuda/CUDAGuard.h>
#endif

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

HeadExecution parse_head_execution(const std::string& name) {
  if (name == "per_head") return HeadExecution::per_head;
  if (name == "grouped") return HeadExecution::grouped;
  if (name == "streams") return HeadExecution::streams;
  fail("OutputHeads: execution must be 'per_head', 'grouped' or 'streams', got '" + name + "'");
}

at::Tensor OutputHeadsImpl::forward(const at::Tensor& features, StreamCache* cache) {
  if (convs.size() == 1) return norm_silu_conv(features, norms[0], convs[0], cache);
  if (execution_ == HeadExecution::grouped) return forward_grouped(features, cache);
  if (execution_ == HeadExecution::streams && features.is_cuda() && !at::GradMode::is_enabled())
    return forward_streams(features, cache);
  std::vector<at::Tensor> outs;
  for (size_t i = 0; i < convs.size(); ++i) outs.push_back(norm_silu_conv(features, norms[i], convs[i], cache));
  return at::cat(outs, 1);
}

// One conv with groups = heads over the concatenated activations; each head's
// output rows are zero-padded to the widest head, and the padding rows are
// dropped afterwards. Differentiable (cat, conv3d, index_select).
at::Tensor OutputHeadsImpl::forward_grouped(const at::Tensor& features, StreamCache* cache) {
  const int64_t K = (int64_t)convs.size();
  int64_t width = 0;
  for (const auto& c : convs) width = std::max(width, c->out_channels());
  std::vector<at::Tensor> acts, weights, biases;
  std::vector<int64_t> keep;
  for (int64_t k = 0; k < K; ++k) {
    CausalConv3d& conv = convs[k];
    acts.push_back(norm_silu_padded(features, norms[k], conv->past_frames(), cache));
    const int64_t c = conv->out_channels(), pad = width - c;
    weights.push_back(pad == 0 ? conv->weight
                               : at::cat({conv->weight, conv->weight.new_zeros({pad, conv->in_channels(), 3, 3, 3})}));
    biases.push_back(pad == 0 ? conv->bias : at::cat({conv->bias, conv->bias.new_zeros({pad})}));
    for (int64_t i = 0; i < c; ++i) keep.push_back(k * width + i);
  }
  const at::Tensor act = at::cat(acts, 1);
  acts.clear();
  const at::Tensor weight = at::cat(weights).to(act.scalar_type()).contiguous(act.suggest_memory_format());
  const at::Tensor out = at::conv3d(act, weight, at::cat(biases).to(act.scalar_type()), {1, 1, 1}, {0, 1, 1},
                                    {1, 1, 1}, K);
  return out.index_select(1, at::tensor(keep, at::TensorOptions().dtype(at::kLong)).to(out.device()));
}

// Each head on its own CUDA stream (the per-head convs leave the GPU
// underused); the caller's stream waits for all of them.
at::Tensor OutputHeadsImpl::forward_streams(const at::Tensor& features, StreamCache* cache) {
#if FLAT_WITH_CUDA
  const c10::cuda::CUDAGuard guard(features.device());
  const c10::cuda::CUDAStream main = at::cuda::getCurrentCUDAStream();
  // The stream cache is advanced in head order on the host, as forward() does.
  std::vector<at::Tensor> padded;
  for (size_t i = 0; i < convs.size(); ++i)
    padded.push_back(norm_silu_padded(features, norms[i], convs[i]->past_frames(), cache));
  at::cuda::CUDAEvent ready;
  ready.record(main);
  std::vector<at::Tensor> outs(convs.size());
  std::vector<at::cuda::CUDAEvent> done(convs.size());
  for (size_t i = 0; i < convs.size(); ++i) {
    const c10::cuda::CUDAStream s = c10::cuda::getStreamFromPool(false, features.device().index());
    ready.block(s);
    {
      const c10::cuda::CUDAStreamGuard on(s);
      outs[i] = convs[i]->forward_prepadded(padded[i]);
    }
    padded[i].record_stream(s);
    outs[i].record_stream(main);
    done[i].record(s);
  }
  for (auto& e : done) e.block(main);
  return at::cat(outs, 1);
#else
  fail("OutputHeads: the 'streams' execution needs a CUDA build");
#endif
}

}  // namespace flat::model
