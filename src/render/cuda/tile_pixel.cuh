// The pixel a compositing thread owns (render/cuda/raster_forward.cu and
// raster_backward.cu): one 8x8-thread block per 8x8-pixel tile of a bin
// group's views (GroupRays, raster_kernels.h), thread
// (threadIdx.x, threadIdx.y) on pixel (tile origin + threadIdx). Each of the
// block's two warps owns one 8x4 half of the tile (its "region": rows 0-3 or
// 4-7) and works through the tile's list on its own, with no block barrier:
// the lane is the pixel's index in the region.
#pragma once
#include "render/cuda/raster_kernels.h"

namespace flat::render::cuda {

constexpr int kRegionW = kTileSize, kRegionH = 32 / kTileSize;  // one warp's pixels
static_assert(kRegionW * kRegionH == 32, "a warp's region is 32 pixels");
constexpr unsigned kFullWarp = 0xffffffffu;

// Camera ray (x, y) with z = 1 through the pixel centre (px, py); multiplied
// by 1 / f, not divided (an IEEE division is ~10 instructions, and the
// backward recomputes a ray per fragment). Within an ulp of the CPU's ray.
static_assert(kBinViews == 2, "pixel_ray picks one of two views");
__device__ __forceinline__ float2 pixel_ray(const GroupRays& rays, int view, float px, float py) {
  const int v = view ? 1 : 0;  // a select between parameters, not an indexed (local-memory) copy
  const float cx = v ? rays.cx[1] : rays.cx[0], cy = v ? rays.cy[1] : rays.cy[0];
  const float ix = v ? rays.inv_fx[1] : rays.inv_fx[0], iy = v ? rays.inv_fy[1] : rays.inv_fy[0];
  return make_float2((px - cx) * ix, (py - cy) * iy);
}

struct TilePixel {
  int view;      // the view of the group: block b composites view b / tiles
  int tile;      // tile index in the view (row-major): tile_order[b]
  int list;      // its entry of the group's ranges (view * tiles + tile)
  int lane;      // pixel index in the warp's region, row-major
  int warp;      // 0: rows 0-3 of the tile, 1: rows 4-7
  int wx0, wy0;  // region origin (pixels)
  int x, y;
  bool inside;   // inside the image (tiles at the right and bottom edges overhang)
  float px, py;  // pixel centre
  float rx, ry;  // camera ray (x, y), z = 1
};

__device__ __forceinline__ TilePixel tile_pixel(const ViewParams& vp, const GroupRays& rays,
                                                const int32_t* __restrict__ tile_order) {
  TilePixel p;
  const int tiles = vp.tiles_x * vp.tiles_y;
  const int tile = tile_order[blockIdx.x];
  p.view = blockIdx.x / tiles;
  p.tile = tile;
  p.list = p.view * tiles + tile;
  const int tid = threadIdx.y * kTileSize + threadIdx.x;
  p.lane = tid & 31;
  p.warp = tid >> 5;
  const int tx = tile % vp.tiles_x, ty = tile / vp.tiles_x;
  p.wx0 = tx * kTileSize;
  p.wy0 = ty * kTileSize + p.warp * kRegionH;
  p.x = p.wx0 + threadIdx.x;
  p.y = ty * kTileSize + threadIdx.y;
  p.inside = p.x < vp.width && p.y < vp.height;
  p.px = p.x + 0.5f;
  p.py = p.y + 0.5f;
  const float2 r = pixel_ray(rays, p.view, p.px, p.py);
  p.rx = r.x;
  p.ry = r.y;
  return p;
}

// Centre of pixel q of the region.
__device__ __forceinline__ float2 region_pixel(const TilePixel& pix, int q) {
  return make_float2(pix.wx0 + (q % kRegionW) + 0.5f, pix.wy0 + (q / kRegionW) + 0.5f);
}

__device__ __forceinline__ unsigned lanes_below(int lane) { return (1u << lane) - 1u; }

// Transpose of the warp's 32x32 bit matrix (lane i's bit j becomes lane j's
// bit i): five butterfly stages, each swapping the off-diagonal blocks of
// side s between lanes i and i ^ s (~30 instructions instead of 32 ballots).
__device__ __forceinline__ unsigned warp_transpose_bits(unsigned x, int lane) {
  const unsigned kLow[5] = {0x0000ffffu, 0x00ff00ffu, 0x0f0f0f0fu, 0x33333333u, 0x55555555u};
#pragma unroll
  for (int i = 0; i < 5; ++i) {
    const int s = 16 >> i;
    const unsigned low = kLow[i];  // the columns j with bit s clear
    const unsigned other = __shfl_xor_sync(kFullWarp, x, s);
    x = (lane & s) ? (x & ~low) | ((other >> s) & low) : (x & low) | ((other & low) << s);
  }
  return x;
}

}  // namespace flat::render::cuda
