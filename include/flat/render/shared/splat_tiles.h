// The tiles of the 3DGS and 2DGS CUDA kernels (gaussians/cuda, surfels/cuda):
// 16 x 16 pixels, one thread a pixel, and the per-view parameters they read.
// Splats cover tens of pixels each, unlike FLAT's ~2x2-pixel triangles (8 x 8
// tiles, render/cuda/raster_kernels.h): larger tiles, fewer pairs. Plain
// header (no torch, no CUDA intrinsics); the device helpers of their
// compositing kernels are in splat_tiles.cuh. Public, under
// flat/render/shared/, because gaussians and surfels include it.
#pragma once
#include "flat/render/shared/compositing.h"
#include "flat/render/shared/view_geometry.h"

namespace flat::render::splat {

constexpr int kTileSize = 16;
constexpr int kBlockSize = kTileSize * kTileSize;

using ViewParams = TileView<CompositingConstants>;

// Tiles [x / kTileSize] touched by pixels [x0, x1) (x1 > x0).
FLAT_HD int tile_lo(int x0) { return x0 / kTileSize; }
FLAT_HD int tile_hi(int x1) { return (x1 - 1) / kTileSize + 1; }

// The number of tiles a pixel rectangle touches.
FLAT_HD int tiles_touched(const PixelRect& r) {
  return (tile_hi(r.x1) - tile_lo(r.x0)) * (tile_hi(r.y1) - tile_lo(r.y0));
}

}  // namespace flat::render::splat
