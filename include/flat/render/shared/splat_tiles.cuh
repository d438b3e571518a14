// Device helpers the 3DGS and 2DGS compositing kernels share (gaussians/cuda,
// surfels/cuda raster_forward.cu / raster_backward.cu): the pixel a thread
// owns, the block's furthest last entry, the launch of one block a tile.
// CUDA sources only. Public, under flat/render/shared/, because gaussians
// and surfels include it.
#pragma once
#include <cuda_runtime.h>

#include "flat/render/shared/splat_tiles.h"

namespace flat::render::splat {

constexpr unsigned kFullWarp = 0xffffffffu;

// Pixel (x, y) of thread tid in block `tile` (row-major over the tiles),
// whether it lies in the image, and its centre (px, py).
struct TilePixel {
  int x, y;
  bool inside;
  float px, py;
};
__device__ __forceinline__ TilePixel tile_pixel(const ViewParams& vp, int tile, int tid) {
  TilePixel p;
  p.x = (tile % vp.tiles_x) * kTileSize + tid % kTileSize;
  p.y = (tile / vp.tiles_x) * kTileSize + tid / kTileSize;
  p.inside = p.x < vp.width && p.y < vp.height;
  p.px = (float)p.x + 0.5f;
  p.py = (float)p.y + 0.5f;
  return p;
}

// The largest `last` (list entries a pixel processed in the forward) of the
// block: where the backward's replay starts. Every thread calls it.
__device__ __forceinline__ int block_last(int last) {
  __shared__ int block_max;
  if (threadIdx.x == 0) block_max = 0;
  __syncthreads();
  if (last > 0) atomicMax(&block_max, last);
  __syncthreads();
  return block_max;
}

// Thread threadIdx.x of block b of a chunk's launch (one block a tile, the
// views one after another): its view, its pixel, its tile's list range, and
// where the pixel lies in the chunk's images.
struct ChunkPixel {
  int view;
  TilePixel at;
  int2 range;     // the tile's entries in the chunk's sorted list
  int64_t hw;     // pixels a view
  int64_t p;      // the pixel in the chunk's one-channel images (views,H,W)
  int64_t p3;     // channel 0 in its three-channel images (views,3,H,W): channel c at p3 + c * hw
  int64_t first;  // the element of splat 0 in this view (elements: view * per_view + splat)
};
__device__ __forceinline__ ChunkPixel chunk_pixel(const ViewChunk& chunk, const int2* ranges) {
  const int tiles = chunk.v[0].tiles_x * chunk.v[0].tiles_y;
  ChunkPixel c;
  c.view = (int)blockIdx.x / tiles;
  const ViewParams& vp = chunk.v[c.view];
  c.at = tile_pixel(vp, (int)blockIdx.x - c.view * tiles, threadIdx.x);
  c.range = ranges[blockIdx.x];
  c.hw = (int64_t)vp.width * vp.height;
  const int64_t pix = (int64_t)c.at.y * vp.width + c.at.x;
  c.p = c.view * c.hw + pix;
  c.p3 = 3 * c.view * c.hw + pix;
  c.first = (int64_t)c.view * chunk.per_view;
  return c;
}

// Launches `kernel` with one block of kBlockSize threads a tile of every view
// of the chunk (nothing for an empty image).
template <class... Params, class... Args>
void launch_per_chunk_tile(void (*kernel)(Params...), const ViewChunk& chunk, cudaStream_t stream,
                           const Args&... args) {
  const int64_t blocks = int64_t(chunk.v[0].tiles_x) * chunk.v[0].tiles_y * chunk.views;
  if (blocks == 0) return;
  kernel<<<(unsigned)blocks, kBlockSize, 0, stream>>>(args...);
}

// Launches `kernel` with one block of kBlockSize threads a tile of the view
// (nothing for an empty image).
template <class... Params, class... Args>
void launch_per_tile(void (*kernel)(Params...), const ViewParams& vp, cudaStream_t stream, const Args&... args) {
  const int tiles = vp.tiles_x * vp.tiles_y;
  if (tiles == 0) return;
  kernel<<<tiles, kBlockSize, 0, stream>>>(args...);
}

}  // namespace flat::render::splat
