// Tile binning of one view: the prefix sum of the tiles each Gaussian touches,
// one (key, id) pair per touched tile with key = tile << 24 | depth key
// (render::depth_sort_key: 24 bits of the positive camera depth of the mean),
// a stable radix sort of the pairs on the bits the key uses (cub), and each
// tile's range in the sorted list. Pairs are written in Gaussian order and
// the sort is stable, so equal depth keys keep index order (as the CPU
// reference's stable sort).
#include <cub/cub.cuh>

#include "gaussians/cuda/gaussian_kernels.h"

namespace flat::gaussians::cuda {
namespace {

constexpr int kThreads = 256;
constexpr int kDepthBits = render::kDepthKeyBits;

__global__ void duplicate_kernel(const int32_t* __restrict__ counts, const int32_t* __restrict__ ends,
                                 const PixelBox* __restrict__ boxes, const uint32_t* __restrict__ depth_keys,
                                 int64_t n, int tiles_x, uint64_t* __restrict__ keys, int32_t* __restrict__ ids) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  const int32_t count = counts[i];
  if (count == 0) return;
  const PixelBox b = boxes[i];
  const uint64_t depth = depth_keys[i];
  int32_t off = ends[i] - count;
  for (int ty = tile_lo(b.y0); ty < tile_hi(b.y1); ++ty)
    for (int tx = tile_lo(b.x0); tx < tile_hi(b.x1); ++tx) {
      keys[off] = ((uint64_t)(ty * tiles_x + tx) << kDepthBits) | depth;
      ids[off] = (int32_t)i;
      ++off;
    }
}

__global__ void tile_ranges_kernel(const uint64_t* __restrict__ keys, int64_t count, int2* __restrict__ ranges) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= count) return;
  const int tile = (int)(keys[i] >> kDepthBits);
  if (i == 0 || (int)(keys[i - 1] >> kDepthBits) != tile) ranges[tile].x = (int)i;
  if (i == count - 1 || (int)(keys[i + 1] >> kDepthBits) != tile) ranges[tile].y = (int)(i + 1);
}

int blocks_of(int64_t n) { return (int)((n + kThreads - 1) / kThreads); }

int bits_for(int values) {
  int b = 1;
  while ((1 << b) < values && b < 31) ++b;
  return b;
}

}  // namespace

void scan_tile_counts(void* temp, size_t& temp_bytes, const int32_t* counts, int32_t* ends, int64_t n,
                      cudaStream_t stream) {
  cub::DeviceScan::InclusiveSum(temp, temp_bytes, counts, ends, (int)n, stream);
}

void launch_duplicate(const int32_t* counts, const int32_t* ends, const PixelBox* boxes, const uint32_t* depth_keys,
                      int64_t n, const ViewParams& vp, uint64_t* keys, int32_t* ids, cudaStream_t stream) {
  if (n == 0) return;
  duplicate_kernel<<<blocks_of(n), kThreads, 0, stream>>>(counts, ends, boxes, depth_keys, n, vp.tiles_x, keys, ids);
}

void sort_pairs(void* temp, size_t& temp_bytes, const uint64_t* keys_in, uint64_t* keys_out, const int32_t* ids_in,
                int32_t* ids_out, int64_t count, int num_tiles, cudaStream_t stream) {
  cub::DeviceRadixSort::SortPairs(temp, temp_bytes, keys_in, keys_out, ids_in, ids_out, (int)count, 0,
                                  kDepthBits + bits_for(num_tiles), stream);
}

void launch_tile_ranges(const uint64_t* sorted_keys, int64_t count, int2* ranges, cudaStream_t stream) {
  if (count == 0) return;
  tile_ranges_kernel<<<blocks_of(count), kThreads, 0, stream>>>(sorted_keys, count, ranges);
}

}  // namespace flat::gaussians::cuda
