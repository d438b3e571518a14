// Fused RMS_norm + SiLU over the channels of a channels-last video tensor:
// y = silu(x * scale / ||x|| * gamma), written straight into the (pre-padded)
// input of the next causal conv.
//
// A group of L lanes owns a pixel: with 16-byte packs, the fewest lanes that
// hold a pixel in at most 4 packs each (4 for 96 bf16 channels, 8 for 192, 16
// for 384), else the whole warp with single elements. Each lane first issues
// all of its loads, then the group reduces with shuffles, so a warp keeps
// 1.5 KB in flight at full occupancy. (The earlier one-warp-per-pixel form had
// one pixel's 192-768 bytes in flight per warp; a first rewrite with up to 16
// packs per lane needed 158 registers, one block per SM: both reached under
// half of the H100's bandwidth.)
#include <cuda_bf16.h>

#include <cstdint>

#include "rms_norm_silu_kernel.h"

namespace flat::model::cuda {
namespace {

constexpr int kThreads = 256;

__device__ inline float to_float(float v) { return v; }
__device__ inline float to_float(__nv_bfloat16 v) { return __bfloat162float(v); }
template <class T>
__device__ inline T from_float(float v);
template <>
__device__ inline float from_float<float>(float v) { return v; }
template <>
__device__ inline __nv_bfloat16 from_float<__nv_bfloat16>(float v) { return __float2bfloat16(v); }

// N consecutive elements moved as one access (16 bytes when N * sizeof(T) = 16).
template <class T, int N>
struct alignas(sizeof(T) * N) Pack {
  T v[N];
};

// L lanes per pixel, N elements per access, at most M accesses per lane; lane
// l of a group handles packs l, l+L, l+2L, ... of its pixel (so a group's
// accesses are contiguous).
template <class T, int N, int L, int M>
__global__ void __launch_bounds__(kThreads)
    rms_norm_silu_kernel(const T* __restrict__ x, const T* __restrict__ gamma, T* __restrict__ out, int64_t rows,
                         int64_t frames, int64_t pixels, int64_t channels, int64_t out_frames, int64_t frame_offset,
                         float scale, bool silu, T* __restrict__ history, int64_t history_frames) {
  using P = Pack<T, N>;
  const int64_t r = (int64_t(blockIdx.x) * kThreads + threadIdx.x) / L;
  const int lane = threadIdx.x % L;
  const bool active = r < rows;  // inactive lanes still join the shuffles
  const int packs = int(channels / N);
  const P* src = reinterpret_cast<const P*>(x + (active ? r : 0) * channels);
  P held[M];
  float ss = 0.f;
#pragma unroll
  for (int k = 0; k < M; ++k) {
    const int i = lane + k * L;
    if (active && i < packs) held[k] = src[i];
  }
#pragma unroll
  for (int k = 0; k < M; ++k) {
    const int i = lane + k * L;
    if (active && i < packs) {
#pragma unroll
      for (int e = 0; e < N; ++e) {
        const float v = to_float(held[k].v[e]);
        ss += v * v;
      }
    }
  }
#pragma unroll
  for (int off = L / 2; off > 0; off /= 2) ss += __shfl_xor_sync(0xffffffffu, ss, off);
  if (!active) return;
  const float inv = scale / fmaxf(sqrtf(ss), 1e-12f);
  // Input row r = (b*frames + t)*pixels + p lands at (b*out_frames + offset + t)*pixels + p.
  const int64_t b = r / (frames * pixels);
  P* dst = reinterpret_cast<P*>(out + (r + (b * (out_frames - frames) + frame_offset) * pixels) * channels);
  // The last history_frames frames also go to `history` (B,history_frames,pixels,C).
  P* hist = nullptr;
  if (history != nullptr) {
    const int64_t t = (r / pixels) % frames, first = frames - history_frames;
    if (t >= first) hist = reinterpret_cast<P*>(history + (r + (b * history_frames - b * frames - first) * pixels) * channels);
  }
  const P* g = reinterpret_cast<const P*>(gamma);
#pragma unroll
  for (int k = 0; k < M; ++k) {
    const int i = lane + k * L;
    if (i < packs) {
      const P gv = g[i];
      P o;
#pragma unroll
      for (int e = 0; e < N; ++e) {
        float v = to_float(held[k].v[e]) * inv * to_float(gv.v[e]);
        if (silu) v = __fdividef(v, 1.f + __expf(-v));  // -> 0 (not NaN) for very negative v
        o.v[e] = from_float<T>(v);
      }
      dst[i] = o;
      if (hist != nullptr) hist[i] = o;
    }
  }
}

template <class T, int N, int L, int M>
void launch(const void* x, const void* gamma, void* out, int64_t rows, int64_t frames, int64_t pixels,
            int64_t channels, int64_t out_frames, int64_t frame_offset, float scale, bool silu, void* history,
            int64_t history_frames, cudaStream_t stream) {
  const int64_t blocks = (rows * L + kThreads - 1) / kThreads;
  rms_norm_silu_kernel<T, N, L, M><<<blocks, kThreads, 0, stream>>>(
      static_cast<const T*>(x), static_cast<const T*>(gamma), static_cast<T*>(out), rows, frames, pixels, channels,
      out_frames, frame_offset, scale, silu, static_cast<T*>(history), history_frames);
}

constexpr int kVecPacks = 4;      // 16-byte packs per lane
constexpr int kScalarPacks = 16;  // elements per lane, warp per pixel

// 16-byte packs with the fewest lanes per pixel that hold it in kVecPacks
// accesses each; else single elements with a warp per pixel.
template <class T>
void dispatch(bool vec, const void* x, const void* gamma, void* out, int64_t rows, int64_t frames, int64_t pixels,
              int64_t channels, int64_t out_frames, int64_t frame_offset, float scale, bool silu, void* history,
              int64_t history_frames, cudaStream_t stream) {
  constexpr int N = 16 / sizeof(T);
  const int64_t packs = channels / N;
  if (vec && packs <= 4 * kVecPacks) {
    launch<T, N, 4, kVecPacks>(x, gamma, out, rows, frames, pixels, channels, out_frames, frame_offset, scale, silu, history,
        history_frames, stream);
  } else if (vec && packs <= 8 * kVecPacks) {
    launch<T, N, 8, kVecPacks>(x, gamma, out, rows, frames, pixels, channels, out_frames, frame_offset, scale, silu, history,
        history_frames, stream);
  } else if (vec && packs <= 16 * kVecPacks) {
    launch<T, N, 16, kVecPacks>(x, gamma, out, rows, frames, pixels, channels, out_frames, frame_offset, scale, silu, history,
        history_frames, stream);
  } else {
    launch<T, 1, 32, kScalarPacks>(x, gamma, out, rows, frames, pixels, channels, out_frames, frame_offset, scale, silu, history,
        history_frames, stream);
  }
}

}  // namespace

bool rms_norm_silu_supported(int64_t channels) { return channels <= 32 * kScalarPacks; }

void launch_rms_norm_silu(const void* x, const void* gamma, void* out, int64_t batch, int64_t frames,
                          int64_t pixels, int64_t channels, int64_t out_frames, int64_t frame_offset,
                          float scale, bool silu, bool is_bf16, void* history, int64_t history_frames,
                          cudaStream_t stream) {
  const int64_t rows = batch * frames * pixels;
  if (rows == 0) return;
  auto aligned = [](const void* ptr) { return reinterpret_cast<uintptr_t>(ptr) % 16 == 0; };
  const bool vec = channels % (is_bf16 ? 8 : 4) == 0 && aligned(x) && aligned(gamma) && aligned(out) &&
                   (history == nullptr || aligned(history));
  if (is_bf16) {
    dispatch<__nv_bfloat16>(vec, x, gamma, out, rows, frames, pixels, channels, out_frames, frame_offset, scale,
                            silu, history, history_frames, stream);
  } else {
    dispatch<float>(vec, x, gamma, out, rows, frames, pixels, channels, out_frames, frame_offset, scale, silu, history,
                    history_frames, stream);
  }
}

}  // namespace flat::model::cuda
