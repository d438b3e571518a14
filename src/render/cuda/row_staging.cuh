// Coalesced block-wide copies between row-major global arrays (rows of W
// floats: vertices 9, colours 3, PixelTri 24, TriGrad rows 20) and a shared-memory
// tile, so that per-triangle kernels read and write whole cache lines instead
// of one scattered 4-byte access per field and thread. Row r of the tile is
// global row rows[base + r] (a gather by triangle id) or, with rows == nullptr,
// base + r. Tile row stride S (odd: no shared-memory bank conflicts when
// thread r then reads its own row). Each thread moves W elements with all its
// loads issued before its stores (a fixed, unrolled trip count: the loads'
// latencies overlap). Callers put __syncthreads() around them.
#pragma once
#include <cstdint>

namespace flat::render::cuda {

__device__ __forceinline__ int64_t staged_row(const int32_t* rows, int64_t base, int r) {
  return rows ? (int64_t)rows[base + r] : base + r;
}

template <int W, int S, int Threads>
__device__ __forceinline__ void load_rows(const float* __restrict__ src, const int32_t* __restrict__ rows,
                                          int64_t base, int count, float* tile) {
  float v[W];
#pragma unroll
  for (int e = 0; e < W; ++e) {
    const int k = e * Threads + (int)threadIdx.x, r = k / W;
    v[e] = k < count * W ? src[staged_row(rows, base, r) * W + (k - r * W)] : 0.f;
  }
#pragma unroll
  for (int e = 0; e < W; ++e) {
    const int k = e * Threads + (int)threadIdx.x, r = k / W;
    if (k < count * W) tile[r * S + (k - r * W)] = v[e];
  }
}

template <int W, int S, int Threads>
__device__ __forceinline__ void store_rows(const float* tile, const int32_t* __restrict__ rows, int64_t base,
                                           int count, float* __restrict__ dst) {
#pragma unroll
  for (int e = 0; e < W; ++e) {
    const int k = e * Threads + (int)threadIdx.x, r = k / W;
    if (k < count * W) dst[staged_row(rows, base, r) * W + (k - r * W)] = tile[r * S + (k - r * W)];
  }
}

// Zeroes rows [base, base + count) of a contiguous array.
template <int W, int Threads>
__device__ __forceinline__ void zero_rows(float* __restrict__ dst, int64_t base, int count) {
#pragma unroll
  for (int e = 0; e < W; ++e) {
    const int k = e * Threads + (int)threadIdx.x;
    if (k < count * W) dst[base * W + k] = 0.f;
  }
}

// dst += tile (each row appears once in `rows`: no two threads touch one address).
template <int W, int S, int Threads>
__device__ __forceinline__ void add_rows(const float* tile, const int32_t* __restrict__ rows, int64_t base,
                                         int count, float* __restrict__ dst) {
  float v[W];
#pragma unroll
  for (int e = 0; e < W; ++e) {
    const int k = e * Threads + (int)threadIdx.x, r = k / W;
    v[e] = k < count * W ? dst[staged_row(rows, base, r) * W + (k - r * W)] : 0.f;
  }
#pragma unroll
  for (int e = 0; e < W; ++e) {
    const int k = e * Threads + (int)threadIdx.x, r = k / W;
    if (k < count * W) dst[staged_row(rows, base, r) * W + (k - r * W)] = v[e] + tile[r * S + (k - r * W)];
  }
}

}  // namespace flat::render::cuda
