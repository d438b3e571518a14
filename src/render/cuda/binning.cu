// The tile binning of the three rasterizers (flat/render/shared/tile_binning.h
// has the algorithm): the sorts, scans and tile ranges every primitive's
// binning runs, the rectangle footprint of 3DGS and 2DGS (pairs from a pixel
// rectangle and a tile mask), and the triangles' own steps
// (raster_kernels.h): their visible list, their depth keys and their pairs,
// which carry the tile halves the window reaches. Triangle views are binned
// two at a time (a bin group, raster_kernels.h): pair ids index the group's
// visible list, and the tile ids count on through the views.
#include <cub/cub.cuh>
#include <thrust/iterator/counting_iterator.h>

#include "flat/render/shared/tile_binning.h"
#include "render/cuda/raster_kernels.h"

namespace flat::render::cuda {
namespace {

// ---------------------------------------------------------------- shared
__global__ void iota_kernel(int32_t* __restrict__ order, int64_t n) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i < n) order[i] = (int32_t)i;
}

__global__ void gather_counts_kernel(const int32_t* __restrict__ order, int64_t n,
                                     const int32_t* __restrict__ tile_counts, int32_t* __restrict__ counts) {
  const int64_t r = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (r < n) counts[r] = tile_counts[order[r]];
}

__global__ void duplicate_rects_kernel(const int32_t* __restrict__ order, int64_t n, const int32_t* __restrict__ counts,
                                       const int32_t* __restrict__ offsets, const PixelRect* __restrict__ rects,
                                       const uint32_t* __restrict__ masks, int tile_size, int tiles_x,
                                       int64_t per_view, int tiles_per_view, uint32_t* __restrict__ pair_tiles,
                                       int32_t* __restrict__ pair_ids) {
  const int64_t r = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (r >= n || counts[r] == 0) return;
  const int32_t i = order[r];
  // Element i of view i / per_view: its tiles count on after the views before.
  const uint32_t first_tile = per_view > 0 ? (uint32_t)(i / per_view) * (uint32_t)tiles_per_view : 0u;
  const PixelRect b = rects[i];
  const uint32_t mask = masks ? masks[i] : ~0u;  // ~0u: every tile of the rectangle
  const int tx0 = b.x0 / tile_size, tx1 = (b.x1 - 1) / tile_size + 1;
  const int ty0 = b.y0 / tile_size, ty1 = (b.y1 - 1) / tile_size + 1;
  int32_t off = offsets[r];
  int bit = 0;
  for (int ty = ty0; ty < ty1; ++ty)
    for (int tx = tx0; tx < tx1; ++tx, ++bit) {
      if (mask != ~0u && !((mask >> bit) & 1u)) continue;
      pair_tiles[off] = first_tile + (uint32_t)(ty * tiles_x + tx);
      pair_ids[off] = i;
      ++off;
    }
}

struct IsVisible {
  const int32_t* tile_counts;
  __device__ bool operator()(int32_t i) const { return tile_counts[i] > 0; }
};

__global__ void tile_ranges_kernel(const uint32_t* __restrict__ tiles, int64_t count, int2* __restrict__ ranges) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= count) return;
  const int tile = (int)tiles[i];
  if (i == 0 || (int)tiles[i - 1] != tile) ranges[tile].x = (int)i;
  if (i == count - 1 || (int)tiles[i + 1] != tile) ranges[tile].y = (int)(i + 1);
}

// Counting sort of one view's tiles into 256 classes of list length, longest
// first, in one block (a few thousand tiles: one launch instead of a radix
// sort's several); block b sorts view b of the group. The order within a
// class is arbitrary: each tile composites on its own.
constexpr int kOrderThreads = 1024, kLengthClasses = 256;
__global__ void __launch_bounds__(kOrderThreads)
    tile_order_kernel(const int2* __restrict__ group_ranges, int num_tiles, int32_t* __restrict__ group_order) {
  const int2* __restrict__ ranges = group_ranges + (int64_t)blockIdx.x * num_tiles;
  int32_t* __restrict__ order = group_order + (int64_t)blockIdx.x * num_tiles;
  __shared__ int max_len;
  __shared__ int next[kLengthClasses];  // class sizes, then each class's next free position
  const int tid = threadIdx.x;
  if (tid == 0) max_len = 0;
  for (int c = tid; c < kLengthClasses; c += kOrderThreads) next[c] = 0;
  __syncthreads();
  for (int t = tid; t < num_tiles; t += kOrderThreads) atomicMax(&max_len, ranges[t].y - ranges[t].x);
  __syncthreads();
  const int64_t classes_per = (int64_t)max_len + 1;
  auto class_of = [&](int t) {  // 0: the longest lists
    return kLengthClasses - 1 - (int)((int64_t)(ranges[t].y - ranges[t].x) * kLengthClasses / classes_per);
  };
  for (int t = tid; t < num_tiles; t += kOrderThreads) atomicAdd(&next[class_of(t)], 1);
  __syncthreads();
  if (tid < 32) {  // exclusive scan of the class sizes: 8 classes per lane
    constexpr int kPer = kLengthClasses / 32;
    int sum = 0;
    for (int i = 0; i < kPer; ++i) sum += next[tid * kPer + i];
    int incl = sum;
    for (int d = 1; d < 32; d <<= 1) {
      const int up = __shfl_up_sync(0xffffffffu, incl, d);
      if (tid >= d) incl += up;
    }
    int start = incl - sum;
    for (int i = 0; i < kPer; ++i) {
      const int n = next[tid * kPer + i];
      next[tid * kPer + i] = start;
      start += n;
    }
  }
  __syncthreads();
  for (int t = tid; t < num_tiles; t += kOrderThreads) order[atomicAdd(&next[class_of(t)], 1)] = t;
}

// ---------------------------------------------------------------- triangles
__global__ void depth_keys_kernel(const int32_t* __restrict__ visible, int64_t nv, const float* __restrict__ keys,
                                  int32_t first, uint32_t* __restrict__ depth_bits, int32_t* __restrict__ order) {
  const int64_t k = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= nv) return;
  depth_bits[k] = depth_sort_key(keys[visible[k]]);
  order[k] = first + (int32_t)k;
}

__global__ void ordered_counts_kernel(const int32_t* __restrict__ order, int64_t nv, const TriRect* __restrict__ rects,
                                      int32_t* __restrict__ counts) {
  const int64_t r = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (r >= nv) return;
  const TriRect t = rects[order[r]];
  counts[r] = (tile_hi(t.x1) - tile_lo(t.x0)) * (tile_hi(t.y1) - tile_lo(t.y0));
}

// Whether the window support of a triangle (u_i + eps > 0 for all i; eps = 0
// for the TS window) may reach a pixel centre of the pixels [x0, x1) x
// [y0, y1). Each u_i is affine, so its largest value over the box is at one
// corner centre, computed as shade() computes u there; the margin keeps the
// test conservative against rounding at the other centres, where the window
// is then exactly zero. (Edges and box axes are all the separating axes of a
// triangle and a box: the test is exact up to the margin.)
__device__ bool support_meets_box(float sx, float sy, const float nx[3], const float ny[3], float eps, int x0,
                                  int y0, int x1, int y1) {
  constexpr float kMargin = 1e-3f;
  if (x0 >= x1 || y0 >= y1) return false;
#pragma unroll
  for (int i = 0; i < 3; ++i) {
    const float px = (nx[i] >= 0.f ? x1 - 1 : x0) + 0.5f, py = (ny[i] >= 0.f ? y1 - 1 : y0) + 0.5f;
    const float u = 1.f + nx[i] * (px - sx) + ny[i] * (py - sy);
    if (u + eps < -kMargin) return false;
  }
  return true;
}

__global__ void duplicate_kernel(const int32_t* __restrict__ order, int64_t nv, const TriRect* __restrict__ rects,
                                 const PixelTri<float>* __restrict__ tris, ViewParams vp, int32_t second,
                                 const int32_t* __restrict__ offsets, uint32_t* __restrict__ pair_tiles,
                                 int32_t* __restrict__ pair_ids) {
  const int64_t r = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (r >= nv) return;
  const int32_t k = order[r];
  const TriRect t = rects[k];
  const float4* g = reinterpret_cast<const float4*>(tris + k);  // sx, sy, nx, ny: PixelTri's first 8 floats
  const float4 a = g[0], b = g[1];
  const float nx[3] = {a.z, a.w, b.x}, ny[3] = {b.y, b.z, b.w};
  const float eps = vp.k.window == kWindowFlat ? vp.k.eps : 0.f;
  const uint32_t view_tiles = k >= second ? (uint32_t)(vp.tiles_x * vp.tiles_y) : 0u;  // the group's second view
  int32_t off = offsets[r];
  for (int ty = tile_lo(t.y0); ty < tile_hi(t.y1); ++ty)
    for (int tx = tile_lo(t.x0); tx < tile_hi(t.x1); ++tx) {
      const int x0 = max(t.x0, tx * kTileSize), x1 = min(t.x1, (tx + 1) * kTileSize);
      int halves = 0;
      for (int h = 0; h < 2; ++h) {
        const int half_y0 = ty * kTileSize + h * (kTileSize / 2);
        const int y0 = max(t.y0, half_y0), y1 = min(t.y1, half_y0 + kTileSize / 2);
        if (support_meets_box(a.x, a.y, nx, ny, eps, x0, y0, x1, y1)) halves |= 1 << h;
      }
      pair_tiles[off] = view_tiles + (uint32_t)(ty * vp.tiles_x + tx);
      pair_ids[off] = (int32_t)((uint32_t)k | ((uint32_t)halves << kPairIndexBits));
      ++off;
    }
}

int blocks_of(int64_t n) { return (int)((n + 255) / 256); }

int bits_for(int values) {
  int b = 1;
  while ((1 << b) < values && b < 31) ++b;
  return b;
}

}  // namespace

// ---------------------------------------------------------------- shared
void launch_iota(int32_t* order, int64_t n, cudaStream_t stream) {
  if (n == 0) return;
  iota_kernel<<<blocks_of(n), 256, 0, stream>>>(order, n);
}

void launch_gather_counts(const int32_t* order, int64_t n, const int32_t* tile_counts, int32_t* counts,
                          cudaStream_t stream) {
  if (n == 0) return;
  gather_counts_kernel<<<blocks_of(n), 256, 0, stream>>>(order, n, tile_counts, counts);
}

void launch_duplicate_rects(const int32_t* order, int64_t n, const int32_t* counts, const int32_t* offsets,
                            const PixelRect* rects, const uint32_t* masks, int tile_size, int tiles_x,
                            int64_t per_view, int tiles_per_view, uint32_t* pair_tiles, int32_t* pair_ids,
                            cudaStream_t stream) {
  if (n == 0) return;
  duplicate_rects_kernel<<<blocks_of(n), 256, 0, stream>>>(order, n, counts, offsets, rects, masks, tile_size, tiles_x,
                                                           per_view, tiles_per_view, pair_tiles, pair_ids);
}

void sort_by_depth(void* temp, size_t& temp_bytes, const uint32_t* depth_in, uint32_t* depth_out,
                   const int32_t* order_in, int32_t* order_out, int64_t nv, cudaStream_t stream) {
  cub::DeviceRadixSort::SortPairs(temp, temp_bytes, depth_in, depth_out, order_in, order_out, (int)nv, 0, kDepthKeyBits,
                                  stream);
}

void scan_counts(void* temp, size_t& temp_bytes, const int32_t* counts, int32_t* offsets, int64_t nv,
                 cudaStream_t stream) {
  cub::DeviceScan::ExclusiveSum(temp, temp_bytes, counts, offsets, (int)nv, stream);
}

void sort_by_tile(void* temp, size_t& temp_bytes, const uint32_t* tiles_in, uint32_t* tiles_out,
                  const int32_t* ids_in, int32_t* ids_out, int64_t count, int num_tiles, cudaStream_t stream) {
  cub::DeviceRadixSort::SortPairs(temp, temp_bytes, tiles_in, tiles_out, ids_in, ids_out, (int)count, 0,
                                  bits_for(num_tiles), stream);
}

void launch_tile_ranges(const uint32_t* sorted_tiles, int64_t count, int2* ranges, cudaStream_t stream) {
  if (count == 0) return;
  tile_ranges_kernel<<<blocks_of(count), 256, 0, stream>>>(sorted_tiles, count, ranges);
}

void launch_tile_order(const int2* ranges, int num_tiles, int views, int32_t* tile_order, cudaStream_t stream) {
  if (num_tiles == 0 || views == 0) return;
  tile_order_kernel<<<views, kOrderThreads, 0, stream>>>(ranges, num_tiles, tile_order);
}

// ---------------------------------------------------------------- triangles
void select_visible(void* temp, size_t& temp_bytes, const int32_t* tile_counts, int64_t n, int32_t* visible,
                    int32_t* num_visible, cudaStream_t stream) {
  cub::DeviceSelect::If(temp, temp_bytes, thrust::counting_iterator<int32_t>(0), visible, num_visible, (int)n,
                        IsVisible{tile_counts}, stream);
}

void launch_depth_keys(const int32_t* visible, int64_t nv, const float* keys, int32_t first, uint32_t* depth_bits,
                       int32_t* order, cudaStream_t stream) {
  if (nv == 0) return;
  depth_keys_kernel<<<blocks_of(nv), 256, 0, stream>>>(visible, nv, keys, first, depth_bits, order);
}

void launch_ordered_counts(const int32_t* order, int64_t nv, const TriRect* rects, int32_t* counts,
                           cudaStream_t stream) {
  if (nv == 0) return;
  ordered_counts_kernel<<<blocks_of(nv), 256, 0, stream>>>(order, nv, rects, counts);
}

void launch_duplicate(const int32_t* order, int64_t nv, const TriRect* rects, const PixelTri<float>* tris,
                      const ViewParams& vp, int32_t second, const int32_t* offsets, uint32_t* pair_tiles,
                      int32_t* pair_ids, cudaStream_t stream) {
  if (nv == 0) return;
  duplicate_kernel<<<blocks_of(nv), 256, 0, stream>>>(order, nv, rects, tris, vp, second, offsets, pair_tiles,
                                                      pair_ids);
}

}  // namespace flat::render::cuda
