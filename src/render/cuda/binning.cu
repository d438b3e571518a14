// Tile binning: prefix sum of tiles touched, the list of visible triangles,
// one (tile | depth) key per (triangle, tile) pair, stable radix sort (cub),
// per-tile ranges. Key layout: tile id in the high 32 bits, the float bits of
// the (positive) centroid depth in the low 32 bits, so one sort orders tiles,
// then depth. Pair ids are indices into the visible list.
#include <cub/cub.cuh>
#include <thrust/iterator/counting_iterator.h>

#include "render/cuda/raster_kernels.h"

namespace flat::render::cuda {
namespace {

struct IsVisible {
  const int64_t* tile_counts;
  __device__ bool operator()(int32_t i) const { return tile_counts[i] > 0; }
};

__global__ void duplicate_kernel(const int32_t* __restrict__ visible, int64_t nv, const TriRect* __restrict__ rects,
                                 const int64_t* __restrict__ offsets, const float* __restrict__ keys, int tiles_x,
                                 uint64_t* __restrict__ pair_keys, int32_t* __restrict__ pair_ids) {
  const int64_t k = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= nv) return;
  const int32_t i = visible[k];
  const TriRect r = rects[k];
  int64_t off = i == 0 ? 0 : offsets[i - 1];
  const uint64_t depth_bits = __float_as_uint(keys[i]);
  for (int ty = tile_lo(r.y0); ty < tile_hi(r.y1); ++ty)
    for (int tx = tile_lo(r.x0); tx < tile_hi(r.x1); ++tx) {
      pair_keys[off] = ((uint64_t)(ty * tiles_x + tx) << 32) | depth_bits;
      pair_ids[off] = (int32_t)k;
      ++off;
    }
}

__global__ void tile_ranges_kernel(const uint64_t* __restrict__ keys, int64_t count, int2* __restrict__ ranges) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= count) return;
  const int tile = (int)(keys[i] >> 32);
  if (i == 0 || (int)(keys[i - 1] >> 32) != tile) ranges[tile].x = (int)i;
  if (i == count - 1 || (int)(keys[i + 1] >> 32) != tile) ranges[tile].y = (int)(i + 1);
}

int bits_for(int values) {
  int b = 1;
  while ((1 << b) < values && b < 31) ++b;
  return b;
}

}  // namespace

void scan_tile_counts(void* temp, size_t& temp_bytes, const int64_t* tile_counts, int64_t* offsets, int64_t n,
                      cudaStream_t stream) {
  cub::DeviceScan::InclusiveSum(temp, temp_bytes, tile_counts, offsets, (int)n, stream);
}

void select_visible(void* temp, size_t& temp_bytes, const int64_t* tile_counts, int64_t n, int32_t* visible,
                    int32_t* num_visible, cudaStream_t stream) {
  cub::DeviceSelect::If(temp, temp_bytes, thrust::counting_iterator<int32_t>(0), visible, num_visible, (int)n,
                        IsVisible{tile_counts}, stream);
}

void launch_duplicate(const int32_t* visible, int64_t nv, const TriRect* rects, const int64_t* offsets,
                      const float* keys, int tiles_x, uint64_t* pair_keys, int32_t* pair_ids, cudaStream_t stream) {
  if (nv == 0) return;
  duplicate_kernel<<<(int)((nv + 255) / 256), 256, 0, stream>>>(visible, nv, rects, offsets, keys, tiles_x, pair_keys,
                                                                pair_ids);
}

void sort_pairs(void* temp, size_t& temp_bytes, const uint64_t* keys_in, uint64_t* keys_out, const int32_t* ids_in,
                int32_t* ids_out, int64_t count, int num_tiles, cudaStream_t stream) {
  cub::DeviceRadixSort::SortPairs(temp, temp_bytes, keys_in, keys_out, ids_in, ids_out, (int)count, 0,
                                  32 + bits_for(num_tiles), stream);
}

void launch_tile_ranges(const uint64_t* sorted_keys, int64_t count, int2* ranges, cudaStream_t stream) {
  if (count == 0) return;
  tile_ranges_kernel<<<(int)((count + 255) / 256), 256, 0, stream>>>(sorted_keys, count, ranges);
}

}  // namespace flat::render::cuda
