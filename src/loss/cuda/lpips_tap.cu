// One LPIPS tap on channels-last bf16 features, forward and backward: each
// pixel's two feature vectors are normalised (x / (|x| + 1e-10)), and their
// squared difference weighted by the lin layer's w is summed over channels.
// One read of both features forward, one read and one or two writes
// backward, where the ATen form casts to fp32 and makes about ten broadcast
// passes each way.
//
// A group of L lanes owns a pixel (16-byte packs of 8 channels, at most 4 per
// lane, as in model/cuda/rms_norm_silu.cu); the group reduces with shuffles.
#include <cuda_bf16.h>

#include <cstdint>
#include <type_traits>

#include "lpips_tap_kernel.h"

namespace flat::loss::cuda {
namespace {

constexpr int kThreads = 256;
constexpr int kPack = 8;   // bf16 per 16-byte access
constexpr int kPacks = 4;  // accesses per lane
constexpr float kEps = 1e-10f;

struct alignas(16) Pack {
  __nv_bfloat16 v[kPack];
};

template <int L>
__device__ inline float group_sum(float v) {
#pragma unroll
  for (int off = L / 2; off > 0; off /= 2) v += __shfl_xor_sync(0xffffffffu, v, off);
  return v;
}

// Loads row r's packs of a and b held by this lane; returns |a|^2, |b|^2 of
// the pixel (over the group).
template <int L>
__device__ inline void load_row(const Pack* a, const Pack* b, bool active, int lane, int packs, Pack (&ah)[kPacks],
                                Pack (&bh)[kPacks], float& ssa, float& ssb) {
  ssa = 0.f;
  ssb = 0.f;
#pragma unroll
  for (int k = 0; k < kPacks; ++k) {
    const int i = lane + k * L;
    if (active && i < packs) {
      ah[k] = a[i];
      bh[k] = b[i];
    }
  }
#pragma unroll
  for (int k = 0; k < kPacks; ++k) {
    const int i = lane + k * L;
    if (active && i < packs) {
#pragma unroll
      for (int e = 0; e < kPack; ++e) {
        const float x = __bfloat162float(ah[k].v[e]), y = __bfloat162float(bh[k].v[e]);
        ssa += x * x;
        ssb += y * y;
      }
    }
  }
  ssa = group_sum<L>(ssa);
  ssb = group_sum<L>(ssb);
}

template <int L>
__global__ void __launch_bounds__(kThreads)
    lpips_tap_forward_kernel(const __nv_bfloat16* __restrict__ a, const __nv_bfloat16* __restrict__ b,
                             const float* __restrict__ w, float* __restrict__ pixel_out, int64_t rows, int channels) {
  const int64_t r = (int64_t(blockIdx.x) * kThreads + threadIdx.x) / L;
  const int lane = threadIdx.x % L;
  const bool active = r < rows;  // inactive lanes still join the shuffles
  const int packs = channels / kPack;
  const int64_t row = active ? r : 0;
  Pack ah[kPacks], bh[kPacks];
  float ssa, ssb;
  load_row<L>(reinterpret_cast<const Pack*>(a + row * channels), reinterpret_cast<const Pack*>(b + row * channels),
              active, lane, packs, ah, bh, ssa, ssb);
  const float ia = 1.f / (sqrtf(ssa) + kEps), ib = 1.f / (sqrtf(ssb) + kEps);
  float acc = 0.f;
#pragma unroll
  for (int k = 0; k < kPacks; ++k) {
    const int i = lane + k * L;
    if (active && i < packs) {
#pragma unroll
      for (int e = 0; e < kPack; ++e) {
        const float d = __bfloat162float(ah[k].v[e]) * ia - __bfloat162float(bh[k].v[e]) * ib;
        acc += w[i * kPack + e] * d * d;
      }
    }
  }
  acc = group_sum<L>(acc);
  if (active && lane == 0) pixel_out[r] = acc;
}

// With u = x / (n + eps), n = |x|: d u_c / d x_k = delta_ck / (n + eps) -
// x_c x_k / (n (n + eps)^2), so for an upstream g (per channel):
//   grad_x_k = g_k / (n + eps) - x_k / (n (n + eps)^2) sum_c g_c x_c  (0 at n = 0).
// Here g_c = 2 w_c (u_a - u_b)_c * scale for a, and its negative for b.
template <int L>
__global__ void __launch_bounds__(kThreads)
    lpips_tap_backward_kernel(const __nv_bfloat16* __restrict__ a, const __nv_bfloat16* __restrict__ b,
                              const float* __restrict__ w, const float* __restrict__ scale,
                              __nv_bfloat16* __restrict__ grad_a, __nv_bfloat16* __restrict__ grad_b, int64_t rows,
                              int64_t pixels_per_view, int channels) {
  const int64_t r = (int64_t(blockIdx.x) * kThreads + threadIdx.x) / L;
  const int lane = threadIdx.x % L;
  const bool active = r < rows;
  const int packs = channels / kPack;
  const int64_t row = active ? r : 0;
  Pack ah[kPacks], bh[kPacks];
  float ssa, ssb;
  load_row<L>(reinterpret_cast<const Pack*>(a + row * channels), reinterpret_cast<const Pack*>(b + row * channels),
              active, lane, packs, ah, bh, ssa, ssb);
  const float na = sqrtf(ssa), nb = sqrtf(ssb);
  const float ia = 1.f / (na + kEps), ib = 1.f / (nb + kEps);
  const float s = 2.f * scale[row / pixels_per_view];
  float dota = 0.f, dotb = 0.f;  // sum_c g_c a_c, sum_c g_c b_c
#pragma unroll
  for (int k = 0; k < kPacks; ++k) {
    const int i = lane + k * L;
    if (active && i < packs) {
#pragma unroll
      for (int e = 0; e < kPack; ++e) {
        const float x = __bfloat162float(ah[k].v[e]), y = __bfloat162float(bh[k].v[e]);
        const float g = s * w[i * kPack + e] * (x * ia - y * ib);
        dota += g * x;
        dotb += g * y;
      }
    }
  }
  dota = group_sum<L>(dota);
  dotb = group_sum<L>(dotb);
  if (!active) return;
  const float ka = na > 0.f ? dota * ia * ia / na : 0.f, kb = nb > 0.f ? dotb * ib * ib / nb : 0.f;
  Pack* ga = reinterpret_cast<Pack*>(grad_a + r * channels);
  Pack* gb = grad_b != nullptr ? reinterpret_cast<Pack*>(grad_b + r * channels) : nullptr;
#pragma unroll
  for (int k = 0; k < kPacks; ++k) {
    const int i = lane + k * L;
    if (i < packs) {
      Pack oa, ob;
#pragma unroll
      for (int e = 0; e < kPack; ++e) {
        const float x = __bfloat162float(ah[k].v[e]), y = __bfloat162float(bh[k].v[e]);
        const float g = s * w[i * kPack + e] * (x * ia - y * ib);
        oa.v[e] = __float2bfloat16(g * ia - x * ka);
        ob.v[e] = __float2bfloat16(-g * ib + y * kb);
      }
      ga[i] = oa;
      if (gb != nullptr) gb[i] = ob;
    }
  }
}

// The fewest lanes (2, 4, 8 or 16) that hold a pixel in kPacks accesses each.
int lanes_for(int64_t channels) {
  const int64_t packs = channels / kPack;
  int lanes = 2;
  while (lanes * kPacks < packs) lanes *= 2;
  return lanes;
}

int64_t blocks_for(int64_t rows, int lanes) { return (rows * lanes + kThreads - 1) / kThreads; }

// Calls f(std::integral_constant<int, L>) with the lanes per pixel of lanes_for.
template <class F>
void with_lanes(int64_t channels, F&& f) {
  switch (lanes_for(channels)) {
    case 2: return f(std::integral_constant<int, 2>{});
    case 4: return f(std::integral_constant<int, 4>{});
    case 8: return f(std::integral_constant<int, 8>{});
    default: return f(std::integral_constant<int, 16>{});
  }
}

}  // namespace

bool lpips_tap_supported(int64_t channels) {
  return channels > 0 && channels % kPack == 0 && channels <= 16 * kPacks * kPack;
}

void launch_lpips_tap_forward(const void* a, const void* b, const float* w, float* pixel_out, int64_t rows,
                              int64_t channels, cudaStream_t stream) {
  if (rows == 0) return;
  with_lanes(channels, [&](auto lanes) {
    constexpr int L = decltype(lanes)::value;
    lpips_tap_forward_kernel<L><<<blocks_for(rows, L), kThreads, 0, stream>>>(
        static_cast<const __nv_bfloat16*>(a), static_cast<const __nv_bfloat16*>(b), w, pixel_out, rows, int(channels));
  });
}

void launch_lpips_tap_backward(const void* a, const void* b, const float* w, const float* scale, void* grad_a,
                               void* grad_b, int64_t rows, int64_t pixels_per_view, int64_t channels,
                               cudaStream_t stream) {
  if (rows == 0) return;
  with_lanes(channels, [&](auto lanes) {
    constexpr int L = decltype(lanes)::value;
    lpips_tap_backward_kernel<L><<<blocks_for(rows, L), kThreads, 0, stream>>>(
        static_cast<const __nv_bfloat16*>(a), static_cast<const __nv_bfloat16*>(b), w, scale,
        static_cast<__nv_bfloat16*>(grad_a), static_cast<__nv_bfloat16*>(grad_b), rows, pixels_per_view,
        int(channels));
  });
}

}  // namespace flat::loss::cuda
