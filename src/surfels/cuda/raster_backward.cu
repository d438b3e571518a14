// Backward compositing: one block per tile (kTileSize x kTileSize: 16 x 16 as shipped), one thread per pixel, the
// tile's list replayed back to front in rounds of kBlockSize surfels staged in
// shared memory, from the block's furthest last blended entry down. Each pixel
// runs the 3DGS-style recurrence of surfels/cpu/raster_surfels_cpu.cpp (it
// keeps the running sums behind it only as their dot product with its
// upstream gradients), and fragment_backward() (surfels/surfel_math.h) gives
// its gradient of the surfel's screen data. Every thread of the block walks
// the same staged entries in step, so a warp sums its 32 pixels' gradients of
// one surfel with shuffles and adds the 18 sums with one atomic a lane.
#include "flat/render/shared/splat_tiles.cuh"
#include "surfels/cuda/surfel_kernels.h"

namespace flat::surfels::cuda {
namespace {

__global__ void __launch_bounds__(kBlockSize)
    raster_backward_kernel(const int2* __restrict__ ranges, const int32_t* __restrict__ values,
                           const PixelSurfel<float>* __restrict__ surfels, const __grid_constant__ ViewChunk chunk,
                           BackwardImages in, float* __restrict__ surfel_grads) {
  __shared__ PixelSurfel<float> stage[kBlockSize];
  const ChunkPixel cp = chunk_pixel(chunk, ranges);
  const ViewParams& vp = chunk.v[cp.view];
  const int tid = threadIdx.x, lane = tid & 31;
  const auto [x, y, inside, px, py] = cp.at;
  const int2 range = cp.range;
  // rgb, normal and dist: (views,3,H,W); the others (views,H,W).
  const int64_t HW = cp.hw, p = cp.p, p3 = cp.p3;
  // Upstream gradients: r, g, b, depth, nx, ny, nz, alpha, distortion.
  float G[9] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f};
  float T = 1.f, t_final = 1.f, m_ref = 0.f, m1 = 0.f, m2 = 0.f;
  int my_last = 0;
  if (inside) {
#pragma unroll
    for (int c = 0; c < 3; ++c) G[c] = in.g_rgb[c * HW + p3], G[4 + c] = in.g_normal[c * HW + p3];
    G[3] = in.g_depth[p];
    G[7] = in.g_alpha[p];
    G[8] = in.g_distortion[p];
    t_final = T = in.t_final[p];
    my_last = in.last[p];
    m_ref = in.dist[p3];
    m1 = in.dist[HW + p3];
    m2 = in.dist[2 * HW + p3];
  }
  const float w_total = 1.f - t_final;
  // dL/dT_final through the background, times T_final.
  const float bg_t = t_final * (vp.background[0] * G[0] + vp.background[1] * G[1] + vp.background[2] * G[2]);
  float acc_G = 0.f, last_G = 0.f, last_alpha = 0.f;
  const int top = block_last(my_last);
  for (int end = top; end > 0; end -= kBlockSize) {
    const int start = max(0, end - kBlockSize), count = end - start;
    __syncthreads();  // the previous round's reads of the stage
    if (tid < count) stage[tid] = surfels[values[range.x + start + tid]];
    __syncthreads();
    for (int j = count - 1; j >= 0; --j) {
      const PixelSurfel<float>& s = stage[j];
      SurfelGrad<float> g;
      float* gf = reinterpret_cast<float*>(&g);
#pragma unroll
      for (int c = 0; c < kSurfelGradSize; ++c) gf[c] = 0.f;
      SurfelFragment<float> f;
      const bool blends = start + j < my_last && shade(s, px, py, vp.k, f);
      if (blends) {
        const float inv_keep = 1.f / (1.f - f.alpha);
        T *= inv_keep;  // transmittance in front of this surfel
        const float w = f.alpha * T;
        const float m = ndc_depth(f.z) - m_ref;
        const float e = m * m * w_total - 2.f * m * m1 + m2;  // dD/dw
        const float fv_G = s.color[0] * G[0] + s.color[1] * G[1] + s.color[2] * G[2] + f.z * G[3] +
                           s.normal[0] * G[4] + s.normal[1] * G[5] + s.normal[2] * G[6] + G[7] + e * G[8];
        acc_G = last_alpha * last_G + (1.f - last_alpha) * acc_G;  // what lies behind, dotted with G
        const float g_alpha = (fv_G - acc_G) * T - inv_keep * bg_t;
        last_G = fv_G;
        last_alpha = f.alpha;
#pragma unroll
        for (int c = 0; c < 3; ++c) g.color[c] = w * G[c], g.normal[c] = w * G[4 + c];
        const float g_z = w * G[3] + G[8] * 2.f * w * (m * w_total - m1) * ndc_depth_grad(f.z);
        fragment_backward(s, px, py, f, g_alpha, g_z, vp.k, g);
      }
      if (!__any_sync(kFullWarp, blends)) continue;
      // Butterfly sums: every lane gets all 18; lane c adds sum c.
      float mine = 0.f;
#pragma unroll
      for (int c = 0; c < kSurfelGradSize; ++c) {
        float v = gf[c];
#pragma unroll
        for (int d = 16; d > 0; d >>= 1) v += __shfl_xor_sync(kFullWarp, v, d);
        if (lane == c) mine = v;
      }
      if (lane < kSurfelGradSize && mine != 0.f)
        atomicAdd(surfel_grads + (int64_t)kSurfelGradStride * s.index + lane, mine);
    }
  }
}

}  // namespace

void launch_raster_backward(const int2* ranges, const int32_t* values, const PixelSurfel<float>* surfels,
                            const ViewChunk& chunk, const BackwardImages& in, float* surfel_grads,
                            cudaStream_t stream) {
  launch_per_chunk_tile(raster_backward_kernel, chunk, stream, ranges, values, surfels, chunk, in, surfel_grads);
}

}  // namespace flat::surfels::cuda
