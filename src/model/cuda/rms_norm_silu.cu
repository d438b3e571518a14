// Fused RMS_norm + SiLU over the channels of a channels-last video tensor:
// y = silu(x * scale / ||x|| * gamma), written straight into the (pre-padded)
// input of the next causal conv; and its backward (training).
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

#include <algorithm>
#include <cstdint>
#include <initializer_list>

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

// The sum over a group's L lanes (every lane of the group gets it).
template <int L>
__device__ __forceinline__ float group_sum(float v) {
#pragma unroll
  for (int off = L / 2; off > 0; off /= 2) v += __shfl_xor_sync(0xffffffffu, v, off);
  return v;
}

// ||x||^2 of the group's pixel from the packs this lane holds (packs lane,
// lane + L, ...); an inactive lane adds nothing but joins the shuffles.
template <class T, int N, int L, int M>
__device__ __forceinline__ float group_sum_squares(const Pack<T, N> (&held)[M], int lane, int packs, bool active) {
  float ss = 0.f;
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
  return group_sum<L>(ss);
}

// d silu(y) / dy times the output's gradient go.
__device__ __forceinline__ float silu_backward(float y, float go) {
  const float s = 1.f / (1.f + __expf(-y));
  return go * s * (1.f + y * (1.f - s));
}

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
#pragma unroll
  for (int k = 0; k < M; ++k) {
    const int i = lane + k * L;
    if (active && i < packs) held[k] = src[i];
  }
  const float ss = group_sum_squares<T, N, L, M>(held, lane, packs, active);
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

// Lanes per pixel, forward and backward: with 16-byte packs the fewest that
// hold a pixel in kVecPacks accesses each; else 32 (a warp per pixel, single
// elements).
template <class T>
int lanes_for(bool vec, int64_t channels) {
  constexpr int N = 16 / sizeof(T);
  const int64_t packs = channels / N;
  if (vec && packs <= 4 * kVecPacks) return 4;
  if (vec && packs <= 8 * kVecPacks) return 8;
  if (vec && packs <= 16 * kVecPacks) return 16;
  return 32;
}

template <class T>
void dispatch(bool vec, const void* x, const void* gamma, void* out, int64_t rows, int64_t frames, int64_t pixels,
              int64_t channels, int64_t out_frames, int64_t frame_offset, float scale, bool silu, void* history,
              int64_t history_frames, cudaStream_t stream) {
  constexpr int N = 16 / sizeof(T);
  switch (lanes_for<T>(vec, channels)) {
    case 4:
      return launch<T, N, 4, kVecPacks>(x, gamma, out, rows, frames, pixels, channels, out_frames, frame_offset, scale,
                                        silu, history, history_frames, stream);
    case 8:
      return launch<T, N, 8, kVecPacks>(x, gamma, out, rows, frames, pixels, channels, out_frames, frame_offset, scale,
                                        silu, history, history_frames, stream);
    case 16:
      return launch<T, N, 16, kVecPacks>(x, gamma, out, rows, frames, pixels, channels, out_frames, frame_offset, scale,
                                         silu, history, history_frames, stream);
    default:
      return launch<T, 1, 32, kScalarPacks>(x, gamma, out, rows, frames, pixels, channels, out_frames, frame_offset,
                                            scale, silu, history, history_frames, stream);
  }
}

// Backward, per pixel (row) with r = scale / n, n = max(||x||, 1e-12),
// y = g x r, s = sigmoid(y), a = g * go * s (1 + y (1 - s)):
//   dx_c = r a_c - [n > 1e-12] (r / n^2) x_c sum_k a_k x_k
//   dg_c = sum over pixels of (a_c / g_c) x_c r   (= go silu'(y) x_c r)
// Same lane groups as the forward; a block-uniform grid-stride loop so that
// the gamma sums stay in registers, then shared memory, then one partial row
// per block (no global atomics).
template <class T, int N, int L, int M>
__global__ void __launch_bounds__(kThreads)
    rms_norm_silu_backward_kernel(const T* __restrict__ x, const float* __restrict__ gamma,
                                  const T* __restrict__ grad_out, T* __restrict__ grad_x,
                                  float* __restrict__ gamma_partials, int64_t rows, int64_t frames, int64_t pixels,
                                  int64_t channels, int64_t out_frames, int64_t frame_offset, float scale) {
  using P = Pack<T, N>;
  __shared__ float gamma_sum[512];
  for (int c = threadIdx.x; c < channels; c += kThreads) gamma_sum[c] = 0.f;
  const int lane = threadIdx.x % L;
  const int packs = int(channels / N);
  constexpr int kGroups = kThreads / L;
  float dg[M][N];
#pragma unroll
  for (int k = 0; k < M; ++k)
#pragma unroll
    for (int e = 0; e < N; ++e) dg[k][e] = 0.f;
  for (int64_t base = int64_t(blockIdx.x) * kGroups; base < rows; base += int64_t(gridDim.x) * kGroups) {
    const int64_t r = base + threadIdx.x / L;
    const bool active = r < rows;  // inactive lanes still join the shuffles
    const int64_t row = active ? r : 0;
    const int64_t b = row / (frames * pixels);
    const P* xs = reinterpret_cast<const P*>(x + row * channels);
    const P* gos = reinterpret_cast<const P*>(grad_out + (row + (b * (out_frames - frames) + frame_offset) * pixels) * channels);
    P xh[M], gh[M];
#pragma unroll
    for (int k = 0; k < M; ++k) {
      const int i = lane + k * L;
      if (active && i < packs) {
        xh[k] = xs[i];
        gh[k] = gos[i];
      }
    }
    const float n = sqrtf(group_sum_squares<T, N, L, M>(xh, lane, packs, active));
    const float inv = scale / fmaxf(n, 1e-12f);
    float dot = 0.f;  // sum_k a_k x_k
#pragma unroll
    for (int k = 0; k < M; ++k) {
      const int i = lane + k * L;
      if (active && i < packs) {
#pragma unroll
        for (int e = 0; e < N; ++e) {
          const float xv = to_float(xh[k].v[e]), g = gamma[i * N + e];
          const float dy = silu_backward(g * xv * inv, to_float(gh[k].v[e]));
          dot += g * dy * xv;
          dg[k][e] += dy * xv * inv;
        }
      }
    }
    dot = group_sum<L>(dot);
    if (!active) continue;
    const float shrink = n > 1e-12f ? inv / (n * n) * dot : 0.f;
    P* gxs = reinterpret_cast<P*>(grad_x + row * channels);
#pragma unroll
    for (int k = 0; k < M; ++k) {
      const int i = lane + k * L;
      if (i < packs) {
        P o;
#pragma unroll
        for (int e = 0; e < N; ++e) {
          const float xv = to_float(xh[k].v[e]), g = gamma[i * N + e];
          const float dy = silu_backward(g * xv * inv, to_float(gh[k].v[e]));
          o.v[e] = from_float<T>(inv * g * dy - shrink * xv);
        }
        gxs[i] = o;
      }
    }
  }
  __syncthreads();
#pragma unroll
  for (int k = 0; k < M; ++k) {
    const int i = lane + k * L;
    if (i < packs)
#pragma unroll
      for (int e = 0; e < N; ++e) atomicAdd(&gamma_sum[i * N + e], dg[k][e]);
  }
  __syncthreads();
  for (int c = threadIdx.x; c < channels; c += kThreads) gamma_partials[int64_t(blockIdx.x) * channels + c] = gamma_sum[c];
}

constexpr int64_t kBackwardBlocksMax = 2048;

template <int L>
int64_t backward_blocks(int64_t rows) {
  return std::min<int64_t>((rows * L + kThreads - 1) / kThreads, kBackwardBlocksMax);
}

template <class T, int N, int L, int M>
int64_t launch_backward(const void* x, const float* gamma, const void* grad_out, void* grad_x, float* partials,
                     int64_t rows, int64_t frames, int64_t pixels, int64_t channels, int64_t out_frames,
                     int64_t frame_offset, float scale, cudaStream_t stream) {
  const int64_t blocks = backward_blocks<L>(rows);
  rms_norm_silu_backward_kernel<T, N, L, M><<<blocks, kThreads, 0, stream>>>(
      static_cast<const T*>(x), gamma, static_cast<const T*>(grad_out), static_cast<T*>(grad_x), partials, rows,
      frames, pixels, channels, out_frames, frame_offset, scale);
  return blocks;
}

template <class T>
int64_t dispatch_backward(bool vec, const void* x, const float* gamma, const void* grad_out, void* grad_x,
                       float* partials, int64_t rows, int64_t frames, int64_t pixels, int64_t channels,
                       int64_t out_frames, int64_t frame_offset, float scale, cudaStream_t stream) {
  constexpr int N = 16 / sizeof(T);
  switch (lanes_for<T>(vec, channels)) {
    case 4:
      return launch_backward<T, N, 4, kVecPacks>(x, gamma, grad_out, grad_x, partials, rows, frames, pixels,
                                                 channels, out_frames, frame_offset, scale, stream);
    case 8:
      return launch_backward<T, N, 8, kVecPacks>(x, gamma, grad_out, grad_x, partials, rows, frames, pixels,
                                                 channels, out_frames, frame_offset, scale, stream);
    case 16:
      return launch_backward<T, N, 16, kVecPacks>(x, gamma, grad_out, grad_x, partials, rows, frames, pixels,
                                                  channels, out_frames, frame_offset, scale, stream);
    default:
      return launch_backward<T, 1, 32, kScalarPacks>(x, gamma, grad_out, grad_x, partials, rows, frames, pixels,
                                                     channels, out_frames, frame_offset, scale, stream);
  }
}

bool vector_access(int64_t channels, bool is_bf16, std::initializer_list<const void*> pointers) {
  if (channels % (is_bf16 ? 8 : 4) != 0) return false;
  for (const void* p : pointers)
    if (p != nullptr && reinterpret_cast<uintptr_t>(p) % 16 != 0) return false;
  return true;
}

}  // namespace

int64_t rms_norm_silu_backward_max_blocks(int64_t batch, int64_t frames, int64_t pixels) {
  return backward_blocks<32>(batch * frames * pixels);  // the most lanes per pixel: the most blocks
}

int64_t launch_rms_norm_silu_backward(const void* x, const float* gamma, const void* grad_out, void* grad_x,
                                   float* gamma_partials, int64_t batch, int64_t frames, int64_t pixels,
                                   int64_t channels, int64_t out_frames, int64_t frame_offset, float scale,
                                   bool is_bf16, cudaStream_t stream) {
  const int64_t rows = batch * frames * pixels;
  if (rows == 0) return 0;
  const bool vec = vector_access(channels, is_bf16, {x, grad_out, grad_x});
  if (is_bf16) {
    return dispatch_backward<__nv_bfloat16>(vec, x, gamma, grad_out, grad_x, gamma_partials, rows, frames, pixels, channels,
                                     out_frames, frame_offset, scale, stream);
  }
  return dispatch_backward<float>(vec, x, gamma, grad_out, grad_x, gamma_partials, rows, frames, pixels, channels,
                                  out_frames, frame_offset, scale, stream);
}

bool rms_norm_silu_supported(int64_t channels) { return channels <= 32 * kScalarPacks; }

void launch_rms_norm_silu(const void* x, const void* gamma, void* out, int64_t batch, int64_t frames,
                          int64_t pixels, int64_t channels, int64_t out_frames, int64_t frame_offset,
                          float scale, bool silu, bool is_bf16, void* history, int64_t history_frames,
                          cudaStream_t stream) {
  const int64_t rows = batch * frames * pixels;
  if (rows == 0) return;
  const bool vec = vector_access(channels, is_bf16, {x, gamma, out, history});
  if (is_bf16) {
    dispatch<__nv_bfloat16>(vec, x, gamma, out, rows, frames, pixels, channels, out_frames, frame_offset, scale,
                            silu, history, history_frames, stream);
  } else {
    dispatch<float>(vec, x, gamma, out, rows, frames, pixels, channels, out_frames, frame_offset, scale, silu, history,
                    history_frames, stream);
  }
}

}  // namespace flat::model::cuda
