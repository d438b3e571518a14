// Forward compositing: one block per tile (kTileSize x kTileSize: 16 x 16 as shipped), one thread per pixel. The
// tile's list (front to back) is staged through shared memory kBlockSize records at
// a time; each pixel composites them as the CPU reference does (shade(),
// alpha_min skip, stop before T < t_min). A warp leaves a batch once all its
// pixels are done, the block once all its pixels are. The largest blending
// weight of each Gaussian is reduced over the warp (__reduce_max_sync), then
// over the block in shared memory, and goes to global memory once a tile
// (one atomicMax a tile and Gaussian, not a pixel or a warp). One launch
// renders a chunk of views: block b is tile b % tiles of view b / tiles.
#include "flat/render/shared/splat_tiles.cuh"
#include "gaussians/cuda/gaussian_kernels.h"

namespace flat::gaussians::cuda {
namespace {

__global__ void __launch_bounds__(kBlockSize)
    raster_forward_kernel(const int2* __restrict__ ranges, const int32_t* __restrict__ ids,
                          const ScreenGaussian<float>* __restrict__ screen, const __grid_constant__ ViewChunk chunk,
                          ForwardImages out, unsigned int* __restrict__ max_weight_bits) {
  __shared__ ScreenGaussian<float> sh_g[kBlockSize];
  __shared__ int32_t sh_id[kBlockSize];
  __shared__ unsigned int sh_wmax[kBlockSize];  // the batch's largest weights (float bits)
  const ChunkPixel cp = chunk_pixel(chunk, ranges);
  const ViewParams& vp = chunk.v[cp.view];
  const int tid = threadIdx.x;
  const auto [x, y, inside, px, py] = cp.at;
  const int2 range = cp.range;
  float T = 1.f, acc[4] = {0.f, 0.f, 0.f, 0.f}, median = 0.f;
  int32_t last = 0;
  bool done = !inside;
  // Thread tid owns staged slot tid: it loads it and flushes its largest weight.
  auto flush = [&]() {
    if (sh_wmax[tid] != 0u) atomicMax(max_weight_bits + (sh_id[tid] - cp.first), sh_wmax[tid]);
  };
  bool staged = false;  // a batch is staged and not yet flushed (block-uniform)
  for (int start = range.x; start < range.y; start += kBlockSize) {
    // Also the barrier before this batch's writes: the previous batch is read.
    const int all_done = __syncthreads_count(done);
    if (staged) flush();
    staged = false;
    if (all_done == kBlockSize) break;
    const int e = start + tid;
    sh_wmax[tid] = 0u;
    if (e < range.y) {
      const int32_t id = ids[e];
      sh_id[tid] = id;
      sh_g[tid] = screen[id];
    }
    staged = true;
    __syncthreads();
    const int count = min(kBlockSize, range.y - start);
    for (int j = 0; j < count; ++j) {
      if (__all_sync(kFullWarp, done)) break;
      float w = 0.f;
      if (!done) {
        const ScreenGaussian<float>& g = sh_g[j];
        Fragment<float> f;
        if (shade(g, px, py, vp.k, f)) {
          const float test_T = T * (1.f - f.alpha);
          if (render::stops_before(test_T, vp.k)) {
            done = true;
          } else {
            w = f.alpha * T;
#pragma unroll
            for (int c = 0; c < 3; ++c) acc[c] += w * g.color[c];
            acc[3] += w * g.z;
            if (T > float(render::kMedianTransmittance)) median = g.z;
            T = test_T;
            last = start + j - range.x + 1;
          }
        }
      }
      // Weights are >= 0: their float bits order as the floats.
      const unsigned int wmax = __reduce_max_sync(kFullWarp, __float_as_uint(w));
      if (wmax != 0u && (tid & 31) == 0) atomicMax(sh_wmax + j, wmax);
    }
  }
  if (staged) {  // the list ran out: flush the last batch
    __syncthreads();
    flush();
  }
  if (!inside) return;
  const int64_t p = cp.p;
#pragma unroll
  for (int c = 0; c < 3; ++c) out.rgb[cp.p3 + c * cp.hw] = acc[c] + T * vp.background[c];
  out.alpha[p] = 1.f - T;
  out.depth[p] = acc[3];
  out.median[p] = median;
  if (out.t_final) {
    out.t_final[p] = T;
    out.last[p] = last;
  }
}

}  // namespace

void launch_raster_forward(const int2* ranges, const int32_t* ids, const ScreenGaussian<float>* screen,
                           const ViewChunk& chunk, const ForwardImages& out, unsigned int* max_weight_bits,
                           cudaStream_t stream) {
  launch_per_chunk_tile(raster_forward_kernel, chunk, stream, ranges, ids, screen, chunk, out, max_weight_bits);
}

}  // namespace flat::gaussians::cuda
