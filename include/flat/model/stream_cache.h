// Per-layer state for streaming (chunk by chunk) inference of the Wan VAE.
//
// Every causal layer that looks into the past (k=3 CausalConv3d, the temporal
// convs of upsample3d / downsample3d) takes the next slot, in call order, on
// each chunk. Because the network is the same on every chunk, slot i always
// belongs to the same layer. A slot holds that layer's input history (the last
// 2 frames for k=3 convs, CACHE_T = 2 in the reference; the last frame for the
// stride-2 downsample3d conv). Undefined slot = first chunk.
#pragma once
#include <cstddef>
#include <vector>

#include <ATen/ATen.h>

namespace flat::model {

class StreamCache {
 public:
  // Call before each chunk: layers take their slots again from the first.
  void begin_chunk() { cursor_ = 0; }
  // The slot of the next cached layer (created undefined on the first chunk).
  at::Tensor& next() {
    if (cursor_ == slots_.size()) slots_.emplace_back();
    return slots_[cursor_++];
  }
  size_t size() const { return slots_.size(); }
  void clear() {
    slots_.clear();
    cursor_ = 0;
  }

 private:
  std::vector<at::Tensor> slots_;
  size_t cursor_ = 0;
};

}  // namespace flat::model
