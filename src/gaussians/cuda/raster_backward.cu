// Backward compositing: one block per tile (kTileSize x kTileSize: 16 x 16 as shipped), one thread per pixel,
// replaying the tile's list back to front from the last entry any of its
// pixels blended (the forward's `last`), kBlockSize records a batch through shared
// memory. Each pixel runs the 3DGS recurrence of the CPU reference
// (gaussians/cpu/raster_gaussians_cpu.cpp) over the entries before its own
// last one; the Gaussian's screen gradients (ScreenGrad's 10 fields) are
// summed over the warp with shuffles and added to its row once a warp with
// 16-byte atomics (rows padded to kGradStride floats, one row an element of
// the chunk). One launch replays a chunk of views: block b is tile b % tiles
// of view b / tiles.
#include "flat/render/shared/splat_tiles.cuh"
#include "gaussians/cuda/gaussian_kernels.h"

namespace flat::gaussians::cuda {
namespace {

constexpr int kCh = 5;  // r, g, b, depth, alpha

__global__ void __launch_bounds__(kBlockSize)
    raster_backward_kernel(const int2* __restrict__ ranges, const int32_t* __restrict__ ids,
                           const ScreenGaussian<float>* __restrict__ screen, const __grid_constant__ ViewChunk chunk,
                           BackwardImages in, float* __restrict__ screen_grads) {
  __shared__ ScreenGaussian<float> sh_g[kBlockSize];
  __shared__ int32_t sh_id[kBlockSize];
  const ChunkPixel cp = chunk_pixel(chunk, ranges);
  const ViewParams& vp = chunk.v[cp.view];
  const int tid = threadIdx.x, lane = tid & 31;
  const auto [x, y, inside, px, py] = cp.at;
  const int2 range = cp.range;
  const int64_t p = cp.p;
  float G[kCh] = {0.f, 0.f, 0.f, 0.f, 0.f};
  float T = 1.f, t_final = 1.f;
  int32_t last = 0;
  if (inside) {
#pragma unroll
    for (int c = 0; c < 3; ++c) G[c] = in.g_rgb[cp.p3 + c * cp.hw];
    G[3] = in.g_depth[p];
    G[4] = in.g_alpha[p];
    t_final = T = in.t_final[p];
    last = in.last[p];
  }
  const int block_end = block_last(last);
  const float bg_dot = G[0] * vp.background[0] + G[1] * vp.background[1] + G[2] * vp.background[2];
  float acc[kCh] = {0.f, 0.f, 0.f, 0.f, 0.f}, last_f[kCh] = {0.f, 0.f, 0.f, 0.f, 0.f}, last_alpha = 0.f;
  for (int end = range.x + block_end; end > range.x; end -= kBlockSize) {
    const int begin = max(range.x, end - kBlockSize);
    __syncthreads();              // the previous batch is read
    const int e = end - 1 - tid;  // staged back to front
    if (e >= begin) {
      const int32_t id = ids[e];
      sh_id[tid] = id;
      sh_g[tid] = screen[id];
    }
    __syncthreads();
    const int count = end - begin;
    for (int j = 0; j < count; ++j) {
      const int entry = end - 1 - j - range.x;  // position in the tile's list
      bool valid = entry < last;
      if (!__any_sync(kFullWarp, valid)) continue;
      const ScreenGaussian<float>& g = sh_g[j];
      Fragment<float> f;
      if (valid) valid = shade(g, px, py, vp.k, f);
      ScreenGrad<float> gr = {};
      if (valid) {
        T = T / (1.f - f.alpha);  // transmittance in front of this Gaussian
        const float w = f.alpha * T;
        const float fv[kCh] = {g.color[0], g.color[1], g.color[2], g.z, 1.f};
        float g_alpha = 0.f;
#pragma unroll
        for (int c = 0; c < kCh; ++c) {
          acc[c] = last_alpha * last_f[c] + (1.f - last_alpha) * acc[c];  // what lies behind, composited
          g_alpha += (fv[c] - acc[c]) * G[c];
          last_f[c] = fv[c];
        }
        g_alpha = g_alpha * T - t_final / (1.f - f.alpha) * bg_dot;
        last_alpha = f.alpha;
#pragma unroll
        for (int c = 0; c < 3; ++c) gr.color[c] = w * G[c];
        gr.z = w * G[3];
        shade_backward(g, f, vp.k, g_alpha, gr);
      }
      if (!__any_sync(kFullWarp, valid)) continue;
      float r[kGradStride] = {gr.mean2d[0], gr.mean2d[1], gr.conic[0], gr.conic[1], gr.conic[2], gr.opacity,
                              gr.color[0],  gr.color[1],  gr.color[2], gr.z,        0.f,         0.f};
#pragma unroll
      for (int c = 0; c < kScreenGradSize; ++c)
        for (int d = 16; d > 0; d >>= 1) r[c] += __shfl_down_sync(kFullWarp, r[c], d);
      if (lane == 0) {
        float4* dst = reinterpret_cast<float4*>(screen_grads + (int64_t)kGradStride * sh_id[j]);
#pragma unroll
        for (int v = 0; v < kGradStride / 4; ++v)
          atomicAdd(dst + v, make_float4(r[4 * v], r[4 * v + 1], r[4 * v + 2], r[4 * v + 3]));
      }
    }
  }
}

}  // namespace

void launch_raster_backward(const int2* ranges, const int32_t* ids, const ScreenGaussian<float>* screen,
                            const ViewChunk& chunk, const BackwardImages& in, float* screen_grads, cudaStream_t stream) {
  launch_per_chunk_tile(raster_backward_kernel, chunk, stream, ranges, ids, screen, chunk, in, screen_grads);
}

}  // namespace flat::gaussians::cuda
