// A batch of staged PixelTri records in shared memory, in 16-byte groups
// stored group-major: group g (floats 4g..4g+3) of triangle j at v[g][j]. A
// record moves with six 128-bit loads and stores instead of 24 scalar ones
// (the scalar form throttled the shared-memory pipe: "MIO" stalls were 26% of
// the forward's samples, Nsight Compute, docs/benchmarks.md), and lanes
// reading different triangles read consecutive 16-byte words, free of bank
// conflicts. get_window() reads only the window's inputs (PixelTri puts them
// first), the coverage passes need no more.
#pragma once
#include <cstddef>

#include "flat/render/shared/triangle_math.h"

namespace flat::render::cuda {

template <int Batch>
struct SharedTris {
  static constexpr int kGroups = sizeof(PixelTri<float>) / sizeof(float4);
  static_assert(kGroups * sizeof(float4) == sizeof(PixelTri<float>), "PixelTri is whole 16-byte groups");
  float4 v[kGroups][Batch];

  // Copies record src (global memory, 16-byte aligned) into slot j.
  __device__ __forceinline__ void put(int j, const PixelTri<float>* __restrict__ src) {
    const float4* s = reinterpret_cast<const float4*>(src);
    float4 g[kGroups];
#pragma unroll
    for (int i = 0; i < kGroups; ++i) g[i] = s[i];
#pragma unroll
    for (int i = 0; i < kGroups; ++i) v[i][j] = g[i];
  }
  __device__ __forceinline__ PixelTri<float> get(int j) const { return read(j, kGroups); }
  // sx, sy, nx, ny, opacity, sigma (the rest left unset).
  __device__ __forceinline__ PixelTri<float> get_window(int j) const { return read(j, 3); }
  // The triangle's input row alone (PixelTri::index).
  __device__ __forceinline__ int32_t index(int j) const {
    constexpr int kOffset = offsetof(PixelTri<float>, index);
    return reinterpret_cast<const int32_t*>(&v[kOffset / 16][j])[(kOffset % 16) / 4];
  }

 private:
  __device__ __forceinline__ PixelTri<float> read(int j, int groups) const {
    PixelTri<float> t;
    float4* d = reinterpret_cast<float4*>(&t);
#pragma unroll
    for (int i = 0; i < kGroups; ++i)
      if (i < groups) d[i] = v[i][j];
    return t;
  }
};

}  // namespace flat::render::cuda
