// The pixel a compositing thread owns (render/cuda/raster_forward.cu and
// raster_backward.cu): one 8x8-thread block per 8x8-pixel tile, thread
// (threadIdx.x, threadIdx.y) on pixel (tile origin + threadIdx).
#pragma once
#include "render/cuda/raster_kernels.h"

namespace flat::render::cuda {

// Camera ray (x, y) with z = 1 through the pixel centre (px, py).
__device__ __forceinline__ float2 pixel_ray(const ViewParams& vp, float px, float py) {
  return make_float2((px - vp.cam.cx) / vp.cam.fx, (py - vp.cam.cy) / vp.cam.fy);
}

struct TilePixel {
  int tid;       // thread index in the tile, row-major
  int tx0, ty0;  // tile origin (pixels)
  int x, y;
  bool inside;   // inside the image (tiles at the right and bottom edges overhang)
  float px, py;  // pixel centre
  float rx, ry;  // camera ray (x, y), z = 1
};

__device__ __forceinline__ TilePixel tile_pixel(const ViewParams& vp) {
  TilePixel p;
  p.tid = threadIdx.y * kTileSize + threadIdx.x;
  p.tx0 = blockIdx.x * kTileSize;
  p.ty0 = blockIdx.y * kTileSize;
  p.x = p.tx0 + threadIdx.x;
  p.y = p.ty0 + threadIdx.y;
  p.inside = p.x < vp.width && p.y < vp.height;
  p.px = p.x + 0.5f;
  p.py = p.y + 0.5f;
  const float2 r = pixel_ray(vp, p.px, p.py);
  p.rx = r.x;
  p.ry = r.y;
  return p;
}

}  // namespace flat::render::cuda
