// Launcher of the fused RMS_norm (+ SiLU) kernel. Plain header: no torch types,
// so nvcc never parses libtorch.
#pragma once
#include <cstdint>

#include <cuda_runtime.h>

namespace flat::model::cuda {

// x: channels-last (B,T,HW,C) contiguous; out: (B,out_frames,HW,C) contiguous,
// frames [frame_offset, frame_offset+T) written. y = x / max(||x||,1e-12) *
// scale * gamma[c], then SiLU when `silu`. is_bf16: elements are bfloat16, else float.
// history (may be null): (B,history_frames,HW,C) also receives the last
// history_frames output frames (history_frames <= T): a streaming layer's
// next history without a copy.
// Whether the kernel takes `channels` (<= 512: 16 per lane of a warp).
bool rms_norm_silu_supported(int64_t channels);

void launch_rms_norm_silu(const void* x, const void* gamma, void* out, int64_t batch, int64_t frames,
                          int64_t pixels, int64_t channels, int64_t out_frames, int64_t frame_offset,
                          float scale, bool silu, bool is_bf16, void* history, int64_t history_frames,
                          cudaStream_t stream);

// The backward of launch_rms_norm_silu with silu = true and no history: x and
// grad_x (B,T,HW,C) contiguous; grad_out (B,out_frames,HW,C) contiguous, the
// gradient of the whole padded output (frames [frame_offset, frame_offset+T)
// are read); gamma (C) float. Writes grad_x (the dtype of x) and per-block
// partial sums of the gamma gradient into the first rows of gamma_partials
// (float, rms_norm_silu_backward_max_blocks(...) x C) and returns how many
// rows it wrote: their sum is d/dgamma.
int64_t rms_norm_silu_backward_max_blocks(int64_t batch, int64_t frames, int64_t pixels);
int64_t launch_rms_norm_silu_backward(const void* x, const float* gamma, const void* grad_out, void* grad_x,
                                   float* gamma_partials, int64_t batch, int64_t frames, int64_t pixels,
                                   int64_t channels, int64_t out_frames, int64_t frame_offset, float scale,
                                   bool is_bf16, cudaStream_t stream);

}  // namespace flat::model::cuda
