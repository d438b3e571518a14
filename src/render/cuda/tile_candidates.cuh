// The (staged triangle, tile pixel) candidates of one batch, flattened so that
// the block's threads share them evenly (render/cuda/raster_forward.cu and
// raster_backward.cu). A staged triangle's candidates are the pixels of its
// support rectangle inside the tile; FLAT triangles cover ~3x3 of the 64, from
// 1 to ~25 of them, so giving each triangle one thread left most lanes of a
// warp waiting for the largest (profiled: ~9 of 32 lanes active). Instead an
// exclusive scan of the per-triangle counts numbers all candidates 0..total-1
// and thread t takes candidates t, t + 64, ...; a candidate finds its triangle
// by binary search over the scan (6 steps for 64 triangles).
#pragma once
#include "render/cuda/raster_kernels.h"

namespace flat::render::cuda {

// One staged triangle's rectangle inside the tile, packed: x0, y0 (tile
// pixels, 3 bits each), width w (4 bits), and ceil(2^16 / w) (17 bits) so
// that a candidate's row is (local * recip) >> 16 without a division (exact
// for local < 64).
struct TileBox {
  unsigned int bits;
  __device__ __forceinline__ int x0() const { return bits & 7u; }
  __device__ __forceinline__ int y0() const { return (bits >> 3) & 7u; }
  __device__ __forceinline__ int width() const { return (bits >> 6) & 15u; }
  __device__ __forceinline__ int row_of(int local) const { return (int)(((unsigned)local * (bits >> 10)) >> 16); }
};

// The rectangle r (clipped to the image) inside the tile at (tx0, ty0); count
// = its pixels (0 when it misses the tile).
__device__ __forceinline__ TileBox tile_box(const TriRect& r, int tx0, int ty0, int& count) {
  const int xa = max(r.x0, tx0), xb = min(r.x1, tx0 + kTileSize);
  const int ya = max(r.y0, ty0), yb = min(r.y1, ty0 + kTileSize);
  if (xa >= xb || ya >= yb) {
    count = 0;
    return TileBox{0u};
  }
  const unsigned w = (unsigned)(xb - xa);
  count = (int)w * (yb - ya);
  return TileBox{(unsigned)(xa - tx0) | ((unsigned)(ya - ty0) << 3) | (w << 6) | (((65536u + w - 1u) / w) << 10)};
}

// Exclusive scan of the candidate counts of Batch (32 or 64) staged
// triangles, count[j] in shared memory, into start[0..Batch); start[Batch] =
// total. Call from warp 0 (lane < 32) after a barrier that follows the counts'
// writes; each lane takes Batch / 32 consecutive triangles.
template <int Batch>
__device__ __forceinline__ void scan_candidate_counts(int lane, const int* count, int* start) {
  constexpr int kPer = Batch / 32;
  static_assert(kPer * 32 == Batch, "batches of 32 or 64 triangles");
  int own[kPer], sum = 0;
#pragma unroll
  for (int e = 0; e < kPer; ++e) own[e] = count[kPer * lane + e], sum += own[e];
  int incl = sum;
#pragma unroll
  for (int d = 1; d < 32; d <<= 1) {
    const int up = __shfl_up_sync(0xffffffffu, incl, d);
    if (lane >= d) incl += up;
  }
  int run = incl - sum;
#pragma unroll
  for (int e = 0; e < kPer; ++e) start[kPer * lane + e] = run, run += own[e];
  if (lane == 31) start[Batch] = incl;
}

// Candidate i: its staged triangle j (the last whose start <= i) and tile pixel p.
template <int Batch>
__device__ __forceinline__ void candidate(int i, const int* start, const TileBox* boxes, int& j, int& p) {
  j = 0;
#pragma unroll
  for (int step = Batch / 2; step > 0; step >>= 1)
    if (start[j + step] <= i) j += step;
  const TileBox b = boxes[j];
  const int local = i - start[j];
  const int dy = b.row_of(local);
  p = (b.y0() + dy) * kTileSize + b.x0() + (local - dy * b.width());
}

}  // namespace flat::render::cuda
