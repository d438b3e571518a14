// The (staged triangle, pixel) candidates of one warp's batch, flattened so
// that the warp's lanes share them evenly (render/cuda/raster_forward.cu and
// raster_backward.cu). A staged triangle's candidates are the pixels of its
// support rectangle inside the warp's 8x4 region (render/cuda/tile_pixel.cuh);
// FLAT triangles cover ~3x3 pixels, from 1 to ~25 of them, so giving each
// triangle one lane left most lanes waiting for the largest (profiled: ~9 of
// 32 lanes active). Instead an exclusive scan of the per-triangle counts
// numbers all candidates 0..total-1 and lane l takes candidates l, l + 32,
// ...; a candidate finds its triangle by binary search over the scan.
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

// Candidate i: its staged triangle j (the last whose start <= i) and region
// pixel p. start[0..Batch] is the scan in staging order, start[j] = total
// for unused slots j (so the search never lands on them).
template <int Batch>
__device__ __forceinline__ void candidate(int i, const int* start, const RegionBox* boxes, int& j, int& p) {
  j = 0;
#pragma unroll
  for (int step = Batch / 2; step > 0; step >>= 1)
    if (start[j + step] <= i) j += step;
  const RegionBox b = boxes[j];
  const int local = i - start[j];
  const int dy = b.row_of(local);
  p = (b.y0() + dy) * kRegionW + b.x0() + (local - dy * b.width());
}

}  // namespace flat::render::cuda
