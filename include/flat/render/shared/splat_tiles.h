// The tiles of the 3DGS and 2DGS CUDA kernels (gaussians/cuda, surfels/cuda):
// kTileSize x kTileSize pixels (16 x 16 as shipped), one thread a pixel, and the per-view parameters they read.
// Splats cover tens of pixels each, unlike FLAT's ~2x2-pixel triangles (8 x 8
// tiles, render/cuda/raster_kernels.h): larger tiles, fewer pairs. Plain
// header (no torch, no CUDA intrinsics); the device helpers of their
// compositing kernels are in splat_tiles.cuh. Public, under
// flat/render/shared/, because gaussians and surfels include it.
#pragma once
#include "flat/render/shared/compositing.h"
#include "flat/render/shared/view_geometry.h"

namespace flat::render::splat {

// FLAT_SPLAT_TILE_SIZE (CMake, 8 or 16) builds the other variant for timing.
#ifndef FLAT_SPLAT_TILE_SIZE
#define FLAT_SPLAT_TILE_SIZE 16
#endif
constexpr int kTileSize = FLAT_SPLAT_TILE_SIZE;
static_assert(kTileSize == 8 || kTileSize == 16, "FLAT_SPLAT_TILE_SIZE: 8 or 16 (whole warps a block)");
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
