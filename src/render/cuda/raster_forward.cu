// Forward compositing: one block per 8x8 tile, one thread per pixel. The
// tile's depth-sorted triangles are staged in shared memory in batches of 64,
// and each batch runs in two phases:
//   coverage  the batch's (triangle, pixel) candidates, flattened over the
//             block (render/cuda/tile_candidates.cuh), mark in each pixel's
//             64-bit mask the triangles whose alpha reaches alpha_min;
//   composite each pixel walks its own marked triangles front to back.
// Batches of 64, not 32: the staging (a gather of the batch's records from
// global memory) is latency the block waits through once per batch, and
// halving the batches outweighed keeping alphas in shared memory for the
// composite (which costs occupancy); measured on the anchor workload.
// Same per-pixel semantics as render/cpu/raster_cpu.cpp.
#include "render/cuda/raster_kernels.h"
#include "render/cuda/shared_tris.cuh"
#include "render/cuda/tile_candidates.cuh"
#include "render/cuda/tile_pixel.cuh"

namespace flat::render::cuda {
namespace {

constexpr int kBatch = kBlockSize;  // one 64-bit mask per pixel
static_assert(kBatch == 64, "one 64-bit coverage mask per pixel");

__global__ void __launch_bounds__(kBlockSize)
    raster_forward_kernel(const int2* __restrict__ ranges, const int32_t* __restrict__ ids,
                          const PixelTri<float>* __restrict__ tris, const TriRect* __restrict__ rects,
                          const int32_t* __restrict__ visible, ViewParams vp, ForwardImages out,
                          unsigned int* __restrict__ max_weight_bits) {
  __shared__ SharedTris<kBatch> sh_tri;
  __shared__ TileBox sh_box[kBatch];
  __shared__ int sh_count[kBatch];              // candidates of staged triangle j
  __shared__ int sh_start[kBatch + 1];          // candidates of triangle j: [sh_start[j], sh_start[j + 1])
  __shared__ int32_t sh_id[kBatch];             // triangle id (for max_weight)
  __shared__ unsigned int sh_wmax[kBatch];      // per staged triangle: max weight bits in this tile
  __shared__ unsigned long long sh_hits[kBlockSize];  // per pixel: staged triangles with alpha >= alpha_min
  __shared__ int sh_done[kBlockSize];           // per pixel: compositing finished
  const TilePixel pix = tile_pixel(vp);
  const int2 range = ranges[blockIdx.y * vp.tiles_x + blockIdx.x];
  const int total = range.y - range.x;
  bool done = !pix.inside;
  float T = 1.f, acc[7] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f}, median = 0.f;
  int last = 0;
  for (int base = 0; base < total; base += kBatch) {
    if (__syncthreads_count(done) == kBlockSize) break;
    const int batch = min(kBatch, total - base);
    int count = 0;
    if (pix.tid < batch) {
      const int32_t k = ids[range.x + base + pix.tid];
      sh_id[pix.tid] = visible[k];
      sh_tri.put(pix.tid, tris[k]);
      sh_box[pix.tid] = tile_box(rects[k], pix.tx0, pix.ty0, count);  // rects are clipped to the image
      sh_wmax[pix.tid] = 0u;
    }
    sh_count[pix.tid] = count;
    sh_hits[pix.tid] = 0ull;
    sh_done[pix.tid] = done;
    __syncthreads();
    if (pix.tid < 32) scan_candidate_counts<kBatch>(pix.tid, sh_count, sh_start);
    __syncthreads();
    const int candidates = sh_start[kBatch];
    for (int i = pix.tid; i < candidates; i += kBlockSize) {  // coverage
      int j, p;
      candidate<kBatch>(i, sh_start, sh_box, j, p);
      if (sh_done[p]) continue;
      const PixelTri<float> t = sh_tri.get(j);
      Fragment<float> f;
      shade(t, pix.tx0 + (p % kTileSize) + 0.5f, pix.ty0 + (p / kTileSize) + 0.5f, 0.f, 0.f, vp.k, f);
      if (f.alpha >= vp.k.alpha_min && f.alpha > 0.f) atomicOr(&sh_hits[p], 1ull << j);
    }
    __syncthreads();
    for (unsigned long long m = done ? 0ull : sh_hits[pix.tid]; m != 0ull; m &= m - 1ull) {  // composite, front to back
      const int j = __ffsll((long long)m) - 1;
      const PixelTri<float> t = sh_tri.get(j);
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
      last = base + j + 1;
      // Per-triangle maximum blending weight (non-negative floats order as their bits).
      atomicMax(&sh_wmax[j], __float_as_uint(w));
    }
    __syncthreads();
    if (pix.tid < batch && sh_wmax[pix.tid] != 0u) atomicMax(&max_weight_bits[sh_id[pix.tid]], sh_wmax[pix.tid]);
  }
  if (!pix.inside) return;
  const int64_t HW = (int64_t)vp.width * vp.height, p = (int64_t)pix.y * vp.width + pix.x;
  for (int c = 0; c < 3; ++c) out.rgb[c * HW + p] = acc[c] + T * vp.background[c];
  out.alpha[p] = 1.f - T;
  out.depth[p] = acc[3];
  for (int c = 0; c < 3; ++c) out.normal[c * HW + p] = acc[4 + c];
  out.median[p] = median;
  out.t_final[p] = T;
  out.last[p] = last;
}

}  // namespace

void launch_raster_forward(const int2* ranges, const int32_t* ids, const PixelTri<float>* tris, const TriRect* rects,
                           const int32_t* visible, const ViewParams& vp, const ForwardImages& out,
                           unsigned int* max_weight_bits, cudaStream_t stream) {
  const dim3 grid(vp.tiles_x, vp.tiles_y), block(kTileSize, kTileSize);
  raster_forward_kernel<<<grid, block, 0, stream>>>(ranges, ids, tris, rects, visible, vp, out, max_weight_bits);
}

}  // namespace flat::render::cuda
