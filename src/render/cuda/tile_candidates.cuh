// The (staged triangle, pixel) candidates of one warp's batch, flattened so
// that the warp's lanes share them evenly (render/cuda/raster_forward.cu and
// raster_backward.cu). A staged triangle's candidates are the pixels of its
// support rectangle inside the warp's 8x4 region (render/cuda/tile_pixel.cuh);
// FLAT triangles cover ~3x3 pixels, from 1 to ~25 of them, so giving each
// triangle one lane left most lanes waiting for the largest (profiled: ~9 of
// 32 lanes active). Instead an exclusive scan of the per-triangle counts
// numbers all candidates 0..total-1 and lane l takes candidates l, l + 32,
// ...; a candidate finds its triangle from warp votes over the scan.
#pragma once
#include "render/cuda/tile_pixel.cuh"

namespace flat::render::cuda {

// One staged triangle's rectangle inside the region, packed: x0 (3 bits), y0
// (2 bits), width w (4 bits), and ceil(2^16 / w) (17 bits) so that a
// candidate's row is (local * recip) >> 16 without a division (exact for
// local < 64).
struct RegionBox {
  unsigned int bits;
  __device__ __forceinline__ int x0() const { return bits & 7u; }
  __device__ __forceinline__ int y0() const { return (bits >> 3) & 3u; }
  __device__ __forceinline__ int width() const { return (bits >> 5) & 15u; }
  __device__ __forceinline__ int row_of(int local) const { return (int)(((unsigned)local * (bits >> 9)) >> 16); }
};
static_assert(kRegionW == 8 && kRegionH == 4, "RegionBox packs an 8x4 region");

// The rectangle r (clipped to the image) inside the region at (x0, y0);
// count = its pixels (0 when it misses the region).
__device__ __forceinline__ RegionBox region_box(const TriRect& r, int x0, int y0, int& count) {
  const int xa = max(r.x0, x0), xb = min(r.x1, x0 + kRegionW);
  const int ya = max(r.y0, y0), yb = min(r.y1, y0 + kRegionH);
  if (xa >= xb || ya >= yb) {
    count = 0;
    return RegionBox{0u};
  }
  const unsigned w = (unsigned)(xb - xa);
  count = (int)w * (yb - ya);
  return RegionBox{(unsigned)(xa - x0) | ((unsigned)(ya - y0) << 3) | (w << 5) | (((65536u + w - 1u) / w) << 9)};
}

// Exclusive prefix sum of one value per lane over the warp; total = the sum.
__device__ __forceinline__ int warp_exclusive_scan(int lane, int value, int& total) {
  int incl = value;
#pragma unroll
  for (int d = 1; d < 32; d <<= 1) {
    const int up = __shfl_up_sync(kFullWarp, incl, d);
    if (lane >= d) incl += up;
  }
  total = __shfl_sync(kFullWarp, incl, 31);
  return incl - value;
}

// The candidates of one window [b, b + 32), lane l on candidate b + l: its
// staged slot j (the last whose start <= b + l) and region pixel p. Lanes
// 0..batch-1 hold my_start = start[lane] (the scan in staging order, slots in
// ascending start); lanes from batch on pass total. The slot comes from warp
// votes instead of a binary search over shared memory (five dependent loads):
// the slots started by b, plus those whose start falls in the window at or
// before l. Call with the whole warp; lanes whose b + l >= total get a
// meaningless (j, p) and must not use it.
struct WindowCandidate {
  int j, p;
};
__device__ __forceinline__ WindowCandidate window_candidate(int lane, int b, int my_start, int total,
                                                            const int* start, const RegionBox* boxes) {
  const bool live = my_start < total;  // an unused slot holds total
  const int before = __popc(__ballot_sync(kFullWarp, live && my_start <= b));
  const unsigned heads =
      __reduce_or_sync(kFullWarp, live && my_start > b && my_start < b + 32 ? 1u << (my_start - b) : 0u);
  const int j = max(0, before - 1 + __popc(heads & ((2u << lane) - 1u)));
  const RegionBox box = boxes[j];
  const int local = b + lane - start[j];
  const int dy = box.row_of(local);
  return WindowCandidate{j, (box.y0() + dy) * kRegionW + box.x0() + (local - dy * box.width())};
}

}  // namespace flat::render::cuda
