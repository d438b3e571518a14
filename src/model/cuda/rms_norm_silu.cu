// Fused RMS_norm + SiLU over the channels of a channels-last video tensor, one
// warp per pixel: read the C values, reduce the sum of squares with shuffles,
// write silu(x * scale / ||x|| * gamma) straight into the (pre-padded) output.
#include <cuda_bf16.h>

#include "rms_norm_silu_kernel.h"

namespace flat::model::cuda {
namespace {

__device__ inline float to_float(float v) { return v; }
__device__ inline float to_float(__nv_bfloat16 v) { return __bfloat162float(v); }
template <class T>
__device__ inline T from_float(float v);
template <>
__device__ inline float from_float<float>(float v) { return v; }
template <>
__device__ inline __nv_bfloat16 from_float<__nv_bfloat16>(float v) { return __float2bfloat16(v); }

template <class T>
__global__ void rms_norm_silu_kernel(const T* __restrict__ x, const T* __restrict__ gamma, T* __restrict__ out,
                                     int64_t rows, int64_t frames, int64_t pixels, int64_t channels,
                                     int64_t out_frames, int64_t frame_offset, float scale, bool silu) {
  const int64_t warps_per_block = blockDim.x / 32;
  const int64_t row = int64_t(blockIdx.x) * warps_per_block + threadIdx.x / 32;
  const int lane = threadIdx.x % 32;
  if (row >= rows) return;
  // row = ((b * frames) + t) * pixels + p
  const int64_t p = row % pixels;
  const int64_t bt = row / pixels;
  const int64_t t = bt % frames;
  const int64_t b = bt / frames;
  const T* xr = x + row * channels;
  T* orow = out + ((b * out_frames + frame_offset + t) * pixels + p) * channels;
  float ss = 0.f;
  for (int64_t c = lane; c < channels; c += 32) {
    const float v = to_float(xr[c]);
    ss += v * v;
  }
  for (int off = 16; off > 0; off /= 2) ss += __shfl_xor_sync(0xffffffffu, ss, off);
  const float inv = scale / fmaxf(sqrtf(ss), 1e-12f);
  for (int64_t c = lane; c < channels; c += 32) {
    float v = to_float(xr[c]) * inv * to_float(gamma[c]);
    if (silu) v = v / (1.f + __expf(-v));
    orow[c] = from_float<T>(v);
  }
}

}  // namespace

void launch_rms_norm_silu(const void* x, const void* gamma, void* out, int64_t batch, int64_t frames,
                          int64_t pixels, int64_t channels, int64_t out_frames, int64_t frame_offset,
                          float scale, bool silu, bool is_bf16, cudaStream_t stream) {
  const int64_t rows = batch * frames * pixels;
  if (rows == 0) return;
  const int threads = 256;
  const int64_t blocks = (rows + threads / 32 - 1) / (threads / 32);
  if (is_bf16) {
    rms_norm_silu_kernel<__nv_bfloat16><<<blocks, threads, 0, stream>>>(
        static_cast<const __nv_bfloat16*>(x), static_cast<const __nv_bfloat16*>(gamma),
        static_cast<__nv_bfloat16*>(out), rows, frames, pixels, channels, out_frames, frame_offset, scale, silu);
  } else {
    rms_norm_silu_kernel<float><<<blocks, threads, 0, stream>>>(
        static_cast<const float*>(x), static_cast<const float*>(gamma), static_cast<float*>(out), rows, frames,
        pixels, channels, out_frames, frame_offset, scale, silu);
  }
}

}  // namespace flat::model::cuda
