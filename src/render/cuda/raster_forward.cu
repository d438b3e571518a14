// Forward compositing: one block per 8x8 tile, one thread per pixel, and each
// of the block's two warps works through the tile's depth-sorted list for its
// own 8x4 half (render/cuda/tile_pixel.cuh), synchronising only within the
// warp. Per round the warp reads the next 32 list entries, keeps those whose
// support rectangle meets its half, stages them in shared memory, and runs
// two phases:
//   coverage  the round's (triangle, pixel) candidates, flattened over the
//             lanes (render/cuda/tile_candidates.cuh), mark in each pixel's
//             32-bit mask the triangles whose alpha reaches alpha_min;
//   composite each pixel walks its own marked triangles front to back.
// Why warps and not the block: with block-wide phases, warps that finished a
// phase waited at the barrier for the busiest one (21% of stall samples,
// Nsight Compute, docs/benchmarks.md); a warp also stops as soon as its own 32
// pixels are opaque, and skips the entries that only touch the other half.
// Same per-pixel semantics as render/cpu/raster_cpu.cpp.
#include "render/cuda/raster_kernels.h"
#include "render/cuda/shared_tris.cuh"
#include "render/cuda/tile_candidates.cuh"
#include "render/cuda/tile_pixel.cuh"

namespace flat::render::cuda {
namespace {

constexpr int kBatch = 32;  // list entries read per round: one 32-bit mask per pixel
constexpr int kWarps = kBlockSize / 32;

struct WarpStage {  // one warp's staged triangles (slot j) and per-pixel masks
  SharedTris<kBatch> tri;
  RegionBox box[kBatch];
  int start[kBatch];      // candidates of slot j: [start[j], start[j] + its count)
  int pos[kBatch];        // position in the tile's list
  unsigned int wmax[kBatch];  // max weight bits in this region
  unsigned int hits[32];      // per pixel: slots with alpha >= alpha_min
};

__global__ void __launch_bounds__(kBlockSize)
    raster_forward_kernel(const int2* __restrict__ ranges, const int32_t* __restrict__ tile_order,
                          const int32_t* __restrict__ ids,
                          const PixelTri<float>* __restrict__ tris, const TriRect* __restrict__ rects,
                          ViewParams vp, GroupRays rays, ForwardImages out,
                          unsigned int* __restrict__ max_weight_bits) {
  __shared__ WarpStage stage[kWarps];
  const TilePixel pix = tile_pixel(vp, rays, tile_order);
  WarpStage& sh = stage[pix.warp];
  const int lane = pix.lane;
  const int2 range = ranges[pix.list];
  // This half's coverage masks, indexed by sorted entry (PairMasks).
  uint32_t* const masks = out.masks.bits ? out.masks.bits + pix.warp * out.masks.pairs : nullptr;
  bool done = !pix.inside;
  unsigned done_bits = __ballot_sync(kFullWarp, done);
  float T = 1.f, acc[7] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f}, median = 0.f;
  int last = 0;
  // The list is read ahead: entry ids two rounds early, their rectangles one
  // round early, so a round's gathers wait on loads issued a round before
  // (three dependent global loads per entry: id, rectangle, record).
  // Pair ids (raster_kernels.h; -1: past the list): an entry whose triangle
  // misses this warp's half is skipped without loading its rectangle.
  auto meets = [&](int id) { return id != -1 && pair_meets_half(id, pix.warp); };
  int k_next = range.x + lane < range.y ? ids[range.x + lane] : -1;
  int k_after = range.x + 32 + lane < range.y ? ids[range.x + 32 + lane] : -1;
  TriRect r_next = meets(k_next) ? rects[pair_index(k_next)] : TriRect{0, 0, 0, 0};
  for (int base = range.x; base < range.y && done_bits != kFullWarp; base += kBatch) {
    // Stage the entries of [base, base + 32) that meet this region, in list order.
    const int e = base + lane, k = pair_index(k_next);
    const bool here = meets(k_next);
    const TriRect r = r_next;
    k_next = k_after;
    r_next = meets(k_next) ? rects[pair_index(k_next)] : TriRect{0, 0, 0, 0};
    k_after = base + 64 + lane < range.y ? ids[base + 64 + lane] : -1;
    int count = 0;
    const RegionBox box = here ? region_box(r, pix.wx0, pix.wy0, count) : RegionBox{0u};  // rects are clipped
    const unsigned touching = __ballot_sync(kFullWarp, count > 0);
    if (touching == 0u) {
      if (masks && e < range.y) masks[e] = 0u;
      continue;
    }
    const int batch = __popc(touching), slot = __popc(touching & lanes_below(lane));
    int total;
    const int first = warp_exclusive_scan(lane, count, total);
    if (count > 0) {
      sh.tri.put(slot, tris + k);
      sh.box[slot] = box;
      sh.start[slot] = first;
      sh.pos[slot] = e - range.x;
      sh.wmax[slot] = 0u;
    }
    sh.hits[lane] = 0u;
    __syncwarp();
    const int my_start = lane < batch ? sh.start[lane] : total;
    for (int b = 0; b < total; b += 32) {  // coverage
      const WindowCandidate cand = window_candidate(lane, b, my_start, total, sh.start, sh.box);
      const int j = cand.j, p = cand.p;
      if (b + lane >= total || ((done_bits >> p) & 1u)) continue;
      const PixelTri<float> t = sh.tri.get_window(j);
      const float2 c = region_pixel(pix, p);
      Fragment<float> f;
      shade(t, c.x, c.y, 0.f, 0.f, vp.k, f);
      if (f.alpha >= vp.k.alpha_min && f.alpha > 0.f) atomicOr(&sh.hits[p], 1u << j);
    }
    __syncwarp();
    const unsigned my_hits = sh.hits[lane];
    if (masks) {  // each entry's pixels (slot j's: the hits' column j) for the backward
      const unsigned pixels = __shfl_sync(kFullWarp, warp_transpose_bits(my_hits, lane), slot);
      if (e < range.y) masks[e] = count > 0 ? pixels : 0u;
    }
    int last_j = -1;
    for (unsigned m = done ? 0u : my_hits; m != 0u; m &= m - 1u) {  // composite, front to back
      const int j = __ffs(m) - 1;
      const PixelTri<float> t = sh.tri.get(j);
      Fragment<float> f;
      shade(t, pix.px, pix.py, pix.rx, pix.ry, vp.k, f);
      const float test_T = T * (1.f - f.alpha);
      if (test_T < vp.k.t_min) {
        done = true;
        break;
      }
      fragment_depth(t, pix.rx, pix.ry, f);
      const float w = f.alpha * T;
      acc[0] += w * t.color[0];
      acc[1] += w * t.color[1];
      acc[2] += w * t.color[2];
      acc[3] += w * f.z;
      acc[4] += w * t.normal[0];
      acc[5] += w * t.normal[1];
      acc[6] += w * t.normal[2];
      if (T > 0.5f) median = f.z;
      T = test_T;
      last_j = j;
      // Per-triangle maximum blending weight (non-negative floats order as their bits).
      atomicMax(&sh.wmax[j], __float_as_uint(w));
    }
    if (last_j >= 0) last = sh.pos[last_j] + 1;
    __syncwarp();
    if (lane < batch && sh.wmax[lane] != 0u) atomicMax(&max_weight_bits[sh.tri.index(lane)], sh.wmax[lane]);
    done_bits = __ballot_sync(kFullWarp, done);
    __syncwarp();  // this round's reads of the stage before the next round's writes
  }
  if (!pix.inside) return;
  const int64_t HW = (int64_t)vp.width * vp.height, p = pix.view * HW + (int64_t)pix.y * vp.width + pix.x;
  const int64_t p3 = 2 * pix.view * HW + p;  // three channels a view
  for (int c = 0; c < 3; ++c) out.rgb[c * HW + p3] = acc[c] + T * vp.background[c];
  out.alpha[p] = 1.f - T;
  out.depth[p] = acc[3];
  for (int c = 0; c < 3; ++c) out.normal[c * HW + p3] = acc[4 + c];
  out.median[p] = median;
  out.t_final[p] = T;
  out.last[p] = last;
}

}  // namespace

void launch_raster_forward(const int2* ranges, const int32_t* tile_order, const int32_t* ids,
                           const PixelTri<float>* tris, const TriRect* rects, const ViewParams& vp,
                           const GroupRays& rays, const ForwardImages& out, unsigned int* max_weight_bits,
                           cudaStream_t stream) {
  const dim3 grid(rays.views * vp.tiles_x * vp.tiles_y), block(kTileSize, kTileSize);
  raster_forward_kernel<<<grid, block, 0, stream>>>(ranges, tile_order, ids, tris, rects, vp, rays, out,
                                                    max_weight_bits);
}


}  // namespace flat::render::cuda
