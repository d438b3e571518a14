// Fused 8-bit AdamW step: one launch per parameter tensor, state updated in
// place (the ATen reference dequantises both moments into fp32 tensors,
// updates them op by op and quantises them into new tensors: about a dozen
// launches and 16 bytes of fp32 temporaries per value).
//
// Work split: a warp owns one quantisation block of 256 values, 8 per lane
// (two 16-byte loads of fp32 parameters, one of bf16, 8 bytes of each moment's
// codes), so the block's new absmax is a warp shuffle reduction with no shared
// memory or barrier; 8 warps per thread block loop over the blocks of the
// tensor (grid-stride), so the tables below are staged in shared memory once
// per thread block, not once per 256 values.
//
// Dequantise: m = map[code] * absmax (one fp32 multiply, as the reference).
// Update, op for op as AdamW::update_8bit runs on CUDA, with ATen's roundings
// (libtorch 2.11: the reference's m.lerp_(g, w) with w < 0.5 is m + w (g - m)
// as one fma; v.mul_(b2).addcmul_(g, g, 1 - b2) is fma(1 - b2, g g, v b2)
// (DeviceAddCmulCdiv.cuh); sqrt(v) / sqrt(bias2) multiplies by the float
// reciprocal of the float divisor (div_true_kernel_cuda's CPU-scalar case);
// p.addcdiv_(m, d, s) is fma(s, m / d, p); for bf16 parameters m and the
// denominator are rounded to bf16 first and the parameter after the decay and
// after the update, as the reference's .to() and in-place ops do). Every op is
// an explicit round-to-nearest intrinsic, so no compiler flag (fma
// contraction, fast math) changes it.
// Requantise: absmax = max |x| over the block (padding past numel counts as
// 0); x / absmax (IEEE division; absmax 0 divides by 1), clamped to [-1, 1]
// ([0, 1] unsigned); the code is the number of midpoints below that value,
// as at::bucketize(x, midpoints) (right = false): ties go to the lower code.
// The search runs over the 255 midpoints laid out breadth first (Eytzinger:
// node i has children 2i and 2i+1), so the first 6 of its 8 steps read at
// most 32 consecutive floats across a warp: no bank conflicts there.
//
// Differences from the reference: NaN. The reference's amax propagates a NaN
// into the block's absmax; fmaxf here skips it, and a NaN moment gets code 0
// rather than bucketize's. Finite inputs give the same codes, absmax and
// parameters as the reference, as far as the ATen kernels round as above
// (tests/train/test_adamw8bit_cuda.cpp measures it).
#include <cuda_bf16.h>

#include <algorithm>
#include <cstdint>

#include "adamw8bit_step.h"

namespace flat::optim::cuda {
namespace {

constexpr int kQuant = 256;  // values per quantisation block (kQuantBlock)
constexpr int kPerLane = 8;  // 32 lanes x 8 = one quantisation block per warp
constexpr int kWarps = 8;
constexpr int kThreads = 32 * kWarps;

struct Tables {
  float m_map[256], v_map[256];    // sorted map values: code -> value
  float m_tree[256], v_tree[256];  // midpoints breadth first, from index 1 (0 unused)
};

__device__ inline float to_float(float x) { return x; }
__device__ inline float to_float(__nv_bfloat16 x) { return __bfloat162float(x); }

template <class T>
__device__ inline T from_float(float x);
template <>
__device__ inline float from_float<float>(float x) {
  return x;
}
template <>
__device__ inline __nv_bfloat16 from_float<__nv_bfloat16>(float x) {
  return __float2bfloat16_rn(x);
}

// x rounded to T and back: a T-typed ATen result, or a .to(T).
template <class T>
__device__ inline float round_to(float x) {
  return to_float(from_float<T>(x));
}

// Elements [base, base + 8) of src, zeros past numel. kVec: src is 16-byte
// aligned, and base a multiple of 8, so a full group is one or two 16-byte loads.
template <class T, bool kVec>
__device__ inline void load8(const T* __restrict__ src, int64_t base, int64_t numel, float (&out)[kPerLane]) {
  if (kVec && base + kPerLane <= numel) {
    if constexpr (sizeof(T) == 4) {
      const float4 a = reinterpret_cast<const float4*>(src + base)[0];
      const float4 b = reinterpret_cast<const float4*>(src + base)[1];
      out[0] = a.x, out[1] = a.y, out[2] = a.z, out[3] = a.w;
      out[4] = b.x, out[5] = b.y, out[6] = b.z, out[7] = b.w;
    } else {
      const uint4 raw = *reinterpret_cast<const uint4*>(src + base);
      const uint32_t words[4] = {raw.x, raw.y, raw.z, raw.w};
#pragma unroll
      for (int k = 0; k < 4; ++k) {
        out[2 * k] = __uint_as_float(words[k] << 16);  // bf16 -> float: the high half of the bits
        out[2 * k + 1] = __uint_as_float(words[k] & 0xffff0000u);
      }
    }
    return;
  }
#pragma unroll
  for (int j = 0; j < kPerLane; ++j) out[j] = base + j < numel ? to_float(src[base + j]) : 0.0f;
}

template <class T, bool kVec>
__device__ inline void store8(T* __restrict__ dst, int64_t base, int64_t numel, const float (&x)[kPerLane]) {
  if (kVec && base + kPerLane <= numel) {
    if constexpr (sizeof(T) == 4) {
      reinterpret_cast<float4*>(dst + base)[0] = make_float4(x[0], x[1], x[2], x[3]);
      reinterpret_cast<float4*>(dst + base)[1] = make_float4(x[4], x[5], x[6], x[7]);
    } else {
      uint32_t words[4];
#pragma unroll
      for (int k = 0; k < 4; ++k) {
        const uint32_t lo = __bfloat16_as_ushort(from_float<T>(x[2 * k]));
        const uint32_t hi = __bfloat16_as_ushort(from_float<T>(x[2 * k + 1]));
        words[k] = lo | (hi << 16);
      }
      *reinterpret_cast<uint4*>(dst + base) = make_uint4(words[0], words[1], words[2], words[3]);
    }
    return;
  }
#pragma unroll
  for (int j = 0; j < kPerLane; ++j)
    if (base + j < numel) dst[base + j] = from_float<T>(x[j]);
}

__device__ inline uint32_t code_at(const uint2& c, int j) { return ((j < 4 ? c.x : c.y) >> (8 * (j & 3))) & 0xffu; }

// The number of midpoints below x (0..255): bucketize's index.
__device__ inline uint32_t nearest_code(const float* tree, float x) {
  uint32_t i = 1;
#pragma unroll
  for (int level = 0; level < 8; ++level) i = 2 * i + (tree[i] < x ? 1u : 0u);
  return i - 256;
}

__device__ inline float warp_max(float x) {
#pragma unroll
  for (int offset = 16; offset > 0; offset >>= 1) x = fmaxf(x, __shfl_xor_sync(0xffffffffu, x, offset));
  return x;
}

template <class P, class G, bool kVec>
__global__ void __launch_bounds__(kThreads) adamw8bit_step_kernel(AdamW8bitArgs a) {
  __shared__ Tables tab;
  for (int i = threadIdx.x; i < 256; i += kThreads) {
    tab.m_map[i] = a.m_map[i];
    tab.v_map[i] = a.v_map[i];
    if (i == 0) {
      tab.m_tree[0] = tab.v_tree[0] = 0.0f;
      continue;
    }
    // Node i of level l (i in [2^l, 2^(l+1))) is the in-order element
    // (2 (i - 2^l) + 1) 2^(7-l) - 1 of the sorted midpoints.
    const int level = 31 - __clz(i);
    const int sorted = ((2 * (i - (1 << level)) + 1) << (7 - level)) - 1;
    tab.m_tree[i] = a.m_midpoints[sorted];
    tab.v_tree[i] = a.v_midpoints[sorted];
  }
  if (blockIdx.x == 0 && threadIdx.x == 0) *a.step = a.t;
  __syncthreads();

  P* __restrict__ param = static_cast<P*>(a.param);
  const G* __restrict__ grad = static_cast<const G*>(a.grad);
  const int64_t numel = a.numel;
  const int64_t blocks = (numel + kQuant - 1) / kQuant;
  const int lane = threadIdx.x & 31;
  const bool lerp_small = fabsf(a.lerp_weight) < 0.5f;
  const float lerp_rest = __fsub_rn(1.0f, a.lerp_weight);
  const bool addcmul_one = a.one_minus_beta2 == 1.0f;

  for (int64_t qb = int64_t(blockIdx.x) * kWarps + threadIdx.x / 32; qb < blocks; qb += int64_t(gridDim.x) * kWarps) {
    const int64_t base = qb * kQuant + lane * kPerLane;
    const uint2 mc = *reinterpret_cast<const uint2*>(a.m_codes + base);
    const uint2 vc = *reinterpret_cast<const uint2*>(a.v_codes + base);
    const float m_scale = a.m_absmax[qb], v_scale = a.v_absmax[qb];
    float p[kPerLane], g[kPerLane];
    load8<P, kVec>(param, base, numel, p);
    load8<G, kVec>(grad, base, numel, g);

    float m[kPerLane], v[kPerLane];
    float m_max = 0.0f, v_max = 0.0f;
#pragma unroll
    for (int j = 0; j < kPerLane; ++j) {
      const float m0 = __fmul_rn(tab.m_map[code_at(mc, j)], m_scale);
      const float v0 = __fmul_rn(tab.v_map[code_at(vc, j)], v_scale);
      const float gj = g[j];
      // m.lerp_(g, 1 - beta1)
      const float diff = __fsub_rn(gj, m0);
      const float m1 = lerp_small ? __fmaf_rn(a.lerp_weight, diff, m0) : __fmaf_rn(-diff, lerp_rest, gj);
      // v.mul_(beta2).addcmul_(g, g, 1 - beta2) (ATen fuses g g into the fma when the factor is 1)
      const float vb = __fmul_rn(v0, a.beta2);
      const float v1 = addcmul_one ? __fmaf_rn(gj, gj, vb) : __fmaf_rn(a.one_minus_beta2, __fmul_rn(gj, gj), vb);
      // (v.sqrt() / sqrt(bias2)).add_(eps)
      const float denom = __fadd_rn(__fmul_rn(__fsqrt_rn(v1), a.inv_sqrt_bias2), a.eps);
      // p.mul_(1 - lr wd); p.addcdiv_(m.to(P), denom.to(P), -lr / bias1)
      const float decayed = round_to<P>(__fmul_rn(p[j], a.decay));
      p[j] = round_to<P>(__fmaf_rn(a.step_size, __fdiv_rn(round_to<P>(m1), round_to<P>(denom)), decayed));
      const bool valid = base + j < numel;  // the padding of the last block quantises zeros
      m[j] = valid ? m1 : 0.0f;
      v[j] = valid ? v1 : 0.0f;
      m_max = fmaxf(m_max, fabsf(m[j]));
      v_max = fmaxf(v_max, fabsf(v[j]));
    }
    store8<P, kVec>(param, base, numel, p);

    m_max = warp_max(m_max);
    v_max = warp_max(v_max);
    const float m_div = m_max > 0.0f ? m_max : 1.0f, v_div = v_max > 0.0f ? v_max : 1.0f;
    uint32_t m_words[2] = {0, 0}, v_words[2] = {0, 0};
#pragma unroll
    for (int j = 0; j < kPerLane; ++j) {
      const float mn = fminf(fmaxf(__fdiv_rn(m[j], m_div), -1.0f), 1.0f);
      const float vn = fminf(fmaxf(__fdiv_rn(v[j], v_div), 0.0f), 1.0f);
      m_words[j / 4] |= nearest_code(tab.m_tree, mn) << (8 * (j & 3));
      v_words[j / 4] |= nearest_code(tab.v_tree, vn) << (8 * (j & 3));
    }
    *reinterpret_cast<uint2*>(a.m_codes + base) = make_uint2(m_words[0], m_words[1]);
    *reinterpret_cast<uint2*>(a.v_codes + base) = make_uint2(v_words[0], v_words[1]);
    if (lane == 0) {
      a.m_absmax[qb] = m_max;
      a.v_absmax[qb] = v_max;
    }
  }
}

template <class P, class G, bool kVec>
cudaError_t launch(const AdamW8bitArgs& a, cudaStream_t stream) {
  auto* kernel = adamw8bit_step_kernel<P, G, kVec>;
  static const int per_sm = [&] {
    int n = 0;
    if (cudaOccupancyMaxActiveBlocksPerMultiprocessor(&n, kernel, kThreads, 0) != cudaSuccess) n = 0;
    return std::max(n, 1);
  }();
  int device = 0, sms = 0;
  cudaError_t err = cudaGetDevice(&device);
  if (err == cudaSuccess) err = cudaDeviceGetAttribute(&sms, cudaDevAttrMultiProcessorCount, device);
  if (err != cudaSuccess) return err;
  const int64_t blocks = (a.numel + kQuant - 1) / kQuant;
  const int64_t wanted = (blocks + kWarps - 1) / kWarps;
  // At least one thread block: it also writes the step count.
  const int64_t grid = std::max<int64_t>(1, std::min<int64_t>(wanted, int64_t(sms) * per_sm));
  kernel<<<unsigned(grid), kThreads, 0, stream>>>(a);
  return cudaGetLastError();
}

template <class P, class G>
cudaError_t dispatch_aligned(const AdamW8bitArgs& a, cudaStream_t stream) {
  auto aligned = [](const void* ptr) { return reinterpret_cast<uintptr_t>(ptr) % 16 == 0; };
  return aligned(a.param) && aligned(a.grad) ? launch<P, G, true>(a, stream) : launch<P, G, false>(a, stream);
}

}  // namespace

cudaError_t launch_adamw8bit_step(const AdamW8bitArgs& a, cudaStream_t stream) {
  auto aligned8 = [](const void* ptr) { return reinterpret_cast<uintptr_t>(ptr) % 8 == 0; };
  if (a.numel < 0 || !aligned8(a.m_codes) || !aligned8(a.v_codes)) return cudaErrorInvalidValue;
  if (a.param_bf16)
    return a.grad_bf16 ? dispatch_aligned<__nv_bfloat16, __nv_bfloat16>(a, stream)
                       : dispatch_aligned<__nv_bfloat16, float>(a, stream);
  return a.grad_bf16 ? dispatch_aligned<float, __nv_bfloat16>(a, stream) : dispatch_aligned<float, float>(a, stream);
}

}  // namespace flat::optim::cuda
