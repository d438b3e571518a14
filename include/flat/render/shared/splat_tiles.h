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

// The views one launch renders (their images one after another): each
// kernel reads view v's parameters from its launch's constant bank
// (__grid_constant__), so a chunk is small enough to pass by value. Element
// e = v * per_view + i is splat i in view v of the chunk.
constexpr int kMaxChunkViews = 16;
struct ViewChunk {
  int views = 0;
  int64_t per_view = 0;  // splats (N)
  ViewParams v[kMaxChunkViews];
};

// The views a chunk holds for N splats: as many as kMaxChunkViews and
// kChunkElements (views x splats: the per-element buffers) allow, at least
// one. Forward and backward split the views alike.
constexpr int64_t kChunkElements = int64_t(1) << 24;
inline int chunk_views(int64_t views, int64_t splats) {
  const int64_t fit = splats > 0 ? kChunkElements / splats : kMaxChunkViews;
  const int64_t k = fit < 1 ? 1 : (fit > kMaxChunkViews ? kMaxChunkViews : fit);
  return int(views < k ? (views < 1 ? 1 : views) : k);
}

// The number of tiles a pixel rectangle touches.
FLAT_HD int tiles_touched(const PixelRect& r) {
  return (tile_hi(r.x1) - tile_lo(r.x0)) * (tile_hi(r.y1) - tile_lo(r.y0));
}

}  // namespace flat::render::splat
