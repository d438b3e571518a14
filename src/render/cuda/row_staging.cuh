// Coalesced block-wide copies between row-major global arrays (rows of W
// floats: vertices 9, colours 3, PixelTri 22, TriGrad 21) and a shared-memory
// tile, so that per-triangle kernels read and write whole cache lines instead
// of one scattered 4-byte access per field and thread. Row r of the tile is
// global row rows[base + r] (a gather by triangle id) or, with rows == nullptr,
// base + r. Tile row stride S (odd: no shared-memory bank conflicts when
// thread r then reads its own row). Callers put __syncthreads() around them.
#pragma once
#include <cstdint>

namespace flat::render::cuda {

__device__ __forceinline__ int64_t staged_row(const int32_t* rows, int64_t base, int r) {
  return rows ? (int64_t)rows[base + r] : base + r;
}

template <int W, int S>
__device__ void load_rows(const float* __restrict__ src, const int32_t* __restrict__ rows, int64_t base, int count,
                          float* tile) {
  for (int k = threadIdx.x; k < count * W; k += blockDim.x) {
    const int r = k / W, c = k - r * W;
    tile[r * S + c] = src[staged_row(rows, base, r) * W + c];
  }
}

template <int W, int S>
__device__ void store_rows(const float* tile, const int32_t* __restrict__ rows, int64_t base, int count,
                           float* __restrict__ dst) {
  for (int k = threadIdx.x; k < count * W; k += blockDim.x) {
    const int r = k / W, c = k - r * W;
    dst[staged_row(rows, base, r) * W + c] = tile[r * S + c];
  }
}

// dst += tile (each row appears once in `rows`: no two threads touch one address).
template <int W, int S>
__device__ void add_rows(const float* tile, const int32_t* __restrict__ rows, int64_t base, int count,
                         float* __restrict__ dst) {
  for (int k = threadIdx.x; k < count * W; k += blockDim.x) {
    const int r = k / W, c = k - r * W;
    dst[staged_row(rows, base, r) * W + c] += tile[r * S + c];
  }
}

}  // namespace flat::render::cuda
