// Tile binning: each visible surfel writes one (key, surfel) pair per tile
// its support box touches, key = tile id << 24 | depth key (24 bits); one stable
// radix sort (cub) over those bits alone gives every tile's list
// front to back, ties in surfel order (the pairs are written in surfel order),
// as the CPU reference composites.
#include <cub/cub.cuh>

#include "surfels/cuda/surfel_kernels.h"

namespace flat::surfels::cuda {
namespace {

constexpr int kTileShift = render::kDepthKeyBits;  // tile ids above the depth key

__global__ void duplicate_kernel(const int32_t* __restrict__ offsets, const int32_t* __restrict__ tile_counts,
                                 const SurfelRect* __restrict__ rects, const uint32_t* __restrict__ depth_keys,
                                 int64_t n, int tiles_x, uint64_t* __restrict__ keys, int32_t* __restrict__ values) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  const int32_t count = tile_counts[i];
  if (count == 0) return;
  int64_t off = offsets[i] - count;  // inclusive scan
  const SurfelRect r = rects[i];
  const uint64_t depth = depth_keys[i];
  for (int ty = tile_lo(r.y0); ty < tile_hi(r.y1); ++ty)
    for (int tx = tile_lo(r.x0); tx < tile_hi(r.x1); ++tx) {
      keys[off] = ((uint64_t)(ty * tiles_x + tx) << kTileShift) | depth;
      values[off] = (int32_t)i;
      ++off;
    }
}

__global__ void tile_ranges_kernel(const uint64_t* __restrict__ keys, int64_t count, int2* __restrict__ ranges) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= count) return;
  const int tile = (int)(keys[i] >> kTileShift);
  if (i == 0 || (int)(keys[i - 1] >> kTileShift) != tile) ranges[tile].x = (int)i;
  if (i == count - 1 || (int)(keys[i + 1] >> kTileShift) != tile) ranges[tile].y = (int)(i + 1);
}

int blocks_of(int64_t n) { return (int)((n + 255) / 256); }

int bits_for(int values) {
  int b = 1;
  while ((1 << b) < values && b < 31) ++b;
  return b;
}

}  // namespace

void scan_tile_counts(void* temp, size_t& temp_bytes, const int32_t* counts, int32_t* offsets, int64_t n,
                      cudaStream_t stream) {
  cub::DeviceScan::InclusiveSum(temp, temp_bytes, counts, offsets, (int)n, stream);
}

void launch_duplicate(const int32_t* offsets, const int32_t* tile_counts, const SurfelRect* rects,
                      const uint32_t* depth_keys, int64_t n, const ViewParams& vp, uint64_t* keys, int32_t* values,
                      cudaStream_t stream) {
  if (n == 0) return;
  duplicate_kernel<<<blocks_of(n), 256, 0, stream>>>(offsets, tile_counts, rects, depth_keys, n, vp.tiles_x, keys,
                                                     values);
}

void sort_pairs(void* temp, size_t& temp_bytes, const uint64_t* keys_in, uint64_t* keys_out, const int32_t* values_in,
                int32_t* values_out, int64_t count, int num_tiles, cudaStream_t stream) {
  cub::DeviceRadixSort::SortPairs(temp, temp_bytes, keys_in, keys_out, values_in, values_out, (int)count, 0,
                                  kTileShift + bits_for(num_tiles), stream);
}

void launch_tile_ranges(const uint64_t* sorted_keys, int64_t count, int2* ranges, cudaStream_t stream) {
  if (count == 0) return;
  tile_ranges_kernel<<<blocks_of(count), 256, 0, stream>>>(sorted_keys, count, ranges);
}

}  // namespace flat::surfels::cuda
