// Which of a staged batch of triangles can touch a warp's pixels. A tile of
// 8x8 pixels is two warps of 8x4; FLAT scenes are dominated by ~3x3-pixel
// supports, so a warp skips (without evaluating anything) every staged
// triangle whose support rectangle misses its 32 pixels, instead of running
// the per-triangle code with all lanes idle.
#pragma once
#include <cstdint>

#include "render/cuda/raster_kernels.h"

namespace flat::render::cuda {

constexpr int kWarpRows = 32 / kTileSize;  // pixel rows of a tile per warp
static_assert(kBlockSize == 64, "the batch mask is one 64-bit word");

// Bit j set when entry j < limit of sh_rect meets the pixels [wx0, wx0 + 8) x
// [wy0, wy0 + kWarpRows). Every lane of the warp gets the same mask.
__device__ __forceinline__ uint64_t warp_batch_mask(const TriRect* sh_rect, int limit, int wx0, int wy0, int lane) {
  auto meets = [&](int j) {
    if (j >= limit) return false;
    const TriRect r = sh_rect[j];
    return r.x0 < wx0 + kTileSize && r.x1 > wx0 && r.y0 < wy0 + kWarpRows && r.y1 > wy0;
  };
  const uint64_t lo = __ballot_sync(0xffffffffu, meets(lane));
  const uint64_t hi = __ballot_sync(0xffffffffu, meets(lane + 32));
  return lo | (hi << 32);
}

}  // namespace flat::render::cuda
