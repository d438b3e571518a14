// Tile binning of one view, as the triangle rasterizer's (render/cuda/binning.cu):
// each Gaussian's pairs are the tiles of its mask (preprocess.cu, tile_mask());
// two stable radix sorts (cub): all Gaussians by depth key
// (render::depth_sort_key: 24 bits of the positive camera depth of the mean;
// culled ones last), then the (tile, Gaussian) pairs, written in that depth
// order, by tile id alone (~11 bits at 540x960), so each tile's list comes out
// front to back with equal depth keys in index order (the CPU reference's
// stable sort). Sorting once by depth and then the pairs by a short key moves
// about half the bytes of one sort of the pairs by a 64-bit (tile | depth) key.
#include <cub/cub.cuh>

#include "gaussians/cuda/gaussian_kernels.h"

namespace flat::gaussians::cuda {
namespace {

constexpr int kThreads = 256;

__global__ void ordered_counts_kernel(const int32_t* __restrict__ order, int64_t n,
                                      const int32_t* __restrict__ tile_counts, int32_t* __restrict__ counts) {
  const int64_t r = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (r >= n) return;
  counts[r] = tile_counts[order[r]];
}

__global__ void duplicate_kernel(const int32_t* __restrict__ order, const int32_t* __restrict__ counts,
                                 const int32_t* __restrict__ ends, const PixelBox* __restrict__ boxes,
                                 const uint32_t* __restrict__ tile_masks, int64_t n, int tiles_x,
                                 uint32_t* __restrict__ pair_tiles, int32_t* __restrict__ pair_ids) {
  const int64_t r = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (r >= n) return;
  const int32_t count = counts[r];
  if (count == 0) return;
  const int32_t i = order[r];
  const PixelBox b = boxes[i];
  const uint32_t mask = tile_masks[i];  // the preprocessing's: exactly `count` tiles
  const int tx0 = tile_lo(b.x0), tx1 = tile_hi(b.x1), ty0 = tile_lo(b.y0), ty1 = tile_hi(b.y1);
  const bool every = mask == ~0u && (tx1 - tx0) * (ty1 - ty0) > kMaskTiles;
  int32_t off = ends[r] - count;
  int bit = 0;
  for (int ty = ty0; ty < ty1; ++ty)
    for (int tx = tx0; tx < tx1; ++tx, ++bit) {
      if (!every && !((mask >> bit) & 1u)) continue;
      pair_tiles[off] = (uint32_t)(ty * tiles_x + tx);
      pair_ids[off] = i;
      ++off;
    }
}

__global__ void tile_ranges_kernel(const uint32_t* __restrict__ tiles, int64_t count, int2* __restrict__ ranges) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= count) return;
  const int tile = (int)tiles[i];
  if (i == 0 || (int)tiles[i - 1] != tile) ranges[tile].x = (int)i;
  if (i == count - 1 || (int)tiles[i + 1] != tile) ranges[tile].y = (int)(i + 1);
}

int blocks_of(int64_t n) { return (int)((n + kThreads - 1) / kThreads); }

int bits_for(int values) {
  int b = 1;
  while ((1 << b) < values && b < 31) ++b;
  return b;
}

}  // namespace

void sort_by_depth(void* temp, size_t& temp_bytes, const uint32_t* depth_in, uint32_t* depth_out,
                   const int32_t* order_in, int32_t* order_out, int64_t n, cudaStream_t stream) {
  cub::DeviceRadixSort::SortPairs(temp, temp_bytes, depth_in, depth_out, order_in, order_out, (int)n, 0,
                                  render::kDepthKeyBits, stream);
}

void launch_ordered_counts(const int32_t* order, int64_t n, const int32_t* tile_counts, int32_t* counts,
                           cudaStream_t stream) {
  if (n == 0) return;
  ordered_counts_kernel<<<blocks_of(n), kThreads, 0, stream>>>(order, n, tile_counts, counts);
}

void scan_counts(void* temp, size_t& temp_bytes, const int32_t* counts, int32_t* ends, int64_t n, cudaStream_t stream) {
  cub::DeviceScan::InclusiveSum(temp, temp_bytes, counts, ends, (int)n, stream);
}

void launch_duplicate(const int32_t* order, const int32_t* counts, const int32_t* ends, const PixelBox* boxes,
                      const uint32_t* tile_masks, int64_t n, const ViewParams& vp, uint32_t* pair_tiles,
                      int32_t* pair_ids, cudaStream_t stream) {
  if (n == 0) return;
  duplicate_kernel<<<blocks_of(n), kThreads, 0, stream>>>(order, counts, ends, boxes, tile_masks, n, vp.tiles_x,
                                                          pair_tiles, pair_ids);
}

void sort_by_tile(void* temp, size_t& temp_bytes, const uint32_t* tiles_in, uint32_t* tiles_out, const int32_t* ids_in,
                  int32_t* ids_out, int64_t count, int num_tiles, cudaStream_t stream) {
  cub::DeviceRadixSort::SortPairs(temp, temp_bytes, tiles_in, tiles_out, ids_in, ids_out, (int)count, 0,
                                  bits_for(num_tiles), stream);
}

void launch_tile_ranges(const uint32_t* sorted_tiles, int64_t count, int2* ranges, cudaStream_t stream) {
  if (count == 0) return;
  tile_ranges_kernel<<<blocks_of(count), kThreads, 0, stream>>>(sorted_tiles, count, ranges);
}

}  // namespace flat::gaussians::cuda
