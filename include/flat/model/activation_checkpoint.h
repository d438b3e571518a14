// Activation checkpointing (paper, Training Details: stage 4 trains with
// gradient checkpointing): a block's forward runs without keeping its
// intermediate activations; the backward runs the block again on its saved
// input, with gradients on, and backpropagates through that. Memory: one
// block's activations at a time instead of all of them; time: one more
// forward of each block.
//
// The C++ frontend has no torch.utils.checkpoint: this is a custom autograd
// Function that saves only the input and the autocast state, and in its
// backward calls torch::autograd::backward on the recomputed output (the
// parameters' gradients accumulate there, as in PyTorch's reentrant
// checkpoint). The blocks it wraps must be deterministic (the decoder's are:
// no dropout), so the recomputation equals the original forward.
#pragma once
#include <functional>

#include <ATen/ATen.h>

namespace flat::model {

// y = block(x), without keeping the block's activations when grad mode is on
// and x or the block's parameters need gradients; otherwise just block(x).
at::Tensor checkpointed(const std::function<at::Tensor(const at::Tensor&)>& block, const at::Tensor& x);

}  // namespace flat::model
