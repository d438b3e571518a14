// Backward compositing: each pixel replays its triangles back to front from
// its last contributor (3DGS-style recurrence, as render/cpu/raster_cpu.cpp);
// each fragment adds its triangle's screen gradients (TriGrad) to global
// memory with native float reductions (tiny triangles: few lanes per warp).
#include "render/cuda/raster_kernels.h"

namespace flat::render::cuda {
namespace {

constexpr int kCh = 8;  // r, g, b, depth, nx, ny, nz, alpha
// Offsets of the TriGrad fields in a flat float array (layout of TriGrad<float>).
constexpr int kGS = 0, kGN = 2, kGH = 8, kGZlo = 11, kGZhi = 12, kGNormal = 13, kGColor = 16, kGOpacity = 19,
              kGSigma = 20;

__global__ void __launch_bounds__(kBlockSize)
    raster_backward_kernel(const int2* __restrict__ ranges, const int32_t* __restrict__ ids,
                           const PixelTri<float>* __restrict__ tris, ViewParams vp, BackwardImages in,
                           float* __restrict__ tri_grads) {
  __shared__ PixelTri<float> sh_tri[kBlockSize];
  __shared__ int32_t sh_id[kBlockSize];
  __shared__ int sh_max_last;
  const int tid = threadIdx.y * kTileSize + threadIdx.x;
  const int x = blockIdx.x * kTileSize + threadIdx.x, y = blockIdx.y * kTileSize + threadIdx.y;
  const bool inside = x < vp.width && y < vp.height;
  const float px = x + 0.5f, py = y + 0.5f;
  const float rx = (px - vp.cam.cx) / vp.cam.fx, ry = (py - vp.cam.cy) / vp.cam.fy;
  const int2 range = ranges[blockIdx.y * vp.tiles_x + blockIdx.x];
  const int64_t HW = (int64_t)vp.width * vp.height, p = (int64_t)y * vp.width + x;
  float G[kCh] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f};
  float T = 1.f, t_final = 1.f;
  int my_last = 0;
  if (inside) {
    for (int c = 0; c < 3; ++c) G[c] = in.g_rgb[c * HW + p], G[4 + c] = in.g_normal[c * HW + p];
    G[3] = in.g_depth[p];
    G[7] = in.g_alpha[p];
    t_final = T = in.t_final[p];
    my_last = in.last[p];
  }
  if (tid == 0) sh_max_last = 0;
  __syncthreads();
  atomicMax(&sh_max_last, my_last);
  __syncthreads();
  const int end = sh_max_last;  // entries [0, end) of the tile list matter to some pixel
  const float bgdot = vp.background[0] * G[0] + vp.background[1] * G[1] + vp.background[2] * G[2];
  float acc[kCh] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f}, last_f[kCh] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f};
  float last_alpha = 0.f;
  for (int top = end; top > 0; top -= kBlockSize) {
    const int lo = max(0, top - kBlockSize);
    const int idx = lo + tid;  // stage entries [lo, top)
    __syncthreads();
    if (idx < top) {
      const int32_t id = ids[range.x + idx];
      sh_id[tid] = id;
      sh_tri[tid] = tris[id];
    }
    __syncthreads();
    for (int j = top - 1 - lo; j >= 0; --j) {
      const int rank = lo + j;
      const PixelTri<float>& t = sh_tri[j];
      if (!(inside && rank < my_last)) continue;
      Fragment<float> f;
      shade(t, px, py, rx, ry, vp.k, f);
      if (!(f.alpha >= vp.k.alpha_min && f.alpha > 0.f)) continue;
      fragment_depth(t, rx, ry, f);
      T = T / (1.f - f.alpha);
      const float w = f.alpha * T;
      const float fv[kCh] = {t.color[0], t.color[1], t.color[2], f.z, t.normal[0], t.normal[1], t.normal[2], 1.f};
      float g_alpha = 0.f;
#pragma unroll
      for (int c = 0; c < kCh; ++c) {
        acc[c] = last_alpha * last_f[c] + (1.f - last_alpha) * acc[c];
        g_alpha += (fv[c] - acc[c]) * G[c];
        last_f[c] = fv[c];
      }
      g_alpha = g_alpha * T - t_final / (1.f - f.alpha) * bgdot;
      last_alpha = f.alpha;
      // Straight to global memory: float atomics there are native reductions
      // (RED, fire and forget); shared-memory float atomics are CAS loops.
      float* a = tri_grads + (int64_t)kTriGradSize * sh_id[j];
#pragma unroll
      for (int c = 0; c < 3; ++c) {
        atomicAdd(a + kGColor + c, w * G[c]);
        atomicAdd(a + kGNormal + c, w * G[4 + c]);
      }
      const float g_z = w * G[3];
      if (f.zclamp == 0) {
        const float g_invz = -g_z * f.z * f.z;
        atomicAdd(a + kGH, g_invz * rx);
        atomicAdd(a + kGH + 1, g_invz * ry);
        atomicAdd(a + kGH + 2, g_invz);
      } else {
        atomicAdd(a + (f.zclamp < 0 ? kGZlo : kGZhi), g_z);
      }
      if (t.opacity * f.I < vp.k.alpha_max) {
        atomicAdd(a + kGOpacity, g_alpha * f.I);
        float gu[3], gsig;
        window_backward(f.u, t.sigma, vp.k.eps, vp.k.window, f.I, g_alpha * t.opacity, gu, gsig);
        atomicAdd(a + kGSigma, gsig);
        float gs0 = 0.f, gs1 = 0.f;
#pragma unroll
        for (int i = 0; i < 3; ++i) {
          if (gu[i] == 0.f) continue;
          atomicAdd(a + kGN + 2 * i, gu[i] * (px - t.sx));
          atomicAdd(a + kGN + 2 * i + 1, gu[i] * (py - t.sy));
          gs0 -= gu[i] * t.nx[i];
          gs1 -= gu[i] * t.ny[i];
        }
        atomicAdd(a + kGS, gs0);
        atomicAdd(a + kGS + 1, gs1);
      }
    }
  }
}

}  // namespace

void launch_raster_backward(const int2* ranges, const int32_t* ids, const PixelTri<float>* tris,
                            const ViewParams& vp, const BackwardImages& in, float* tri_grads, cudaStream_t stream) {
  const dim3 grid(vp.tiles_x, vp.tiles_y), block(kTileSize, kTileSize);
  raster_backward_kernel<<<grid, block, 0, stream>>>(ranges, ids, tris, vp, in, tri_grads);
}

}  // namespace flat::render::cuda
