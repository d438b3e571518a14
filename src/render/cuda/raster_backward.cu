// Backward compositing: each pixel replays its triangles back to front from
// its last contributor (3DGS-style recurrence, as render/cpu/raster_cpu.cpp);
// the warp sums each triangle's screen gradients (TriGrad) over its pixels
// and adds them to global memory with one native float reduction per field.
// A warp visits only the staged triangles that can touch its pixels
// (render/cuda/warp_mask.cuh) and that lie before its pixels' last contributor.
#include "render/cuda/raster_kernels.h"
#include "render/cuda/warp_mask.cuh"

namespace flat::render::cuda {
namespace {

constexpr int kCh = 8;  // r, g, b, depth, nx, ny, nz, alpha
// Offsets of the TriGrad fields in a flat float array (layout of TriGrad<float>).
constexpr int kGS = 0, kGN = 2, kGH = 8, kGZlo = 11, kGZhi = 12, kGNormal = 13, kGColor = 16, kGOpacity = 19,
              kGSigma = 20;

// Reduce-scatter over a full warp: returns, in lane c, the sum over the 32
// lanes of v[c]. Recursive halving: at each step a lane keeps half of its
// fields and adds the partner's copy of that half (31 shuffles in all,
// instead of 5 per field for a butterfly of every field).
template <int O>
__device__ __forceinline__ void halve(float (&v)[32], int lane) {
  const bool upper = (lane & O) != 0;
#pragma unroll
  for (int i = 0; i < O; ++i) {
    const float send = upper ? v[i] : v[i + O];
    const float keep = upper ? v[i + O] : v[i];
    v[i] = keep + __shfl_xor_sync(0xffffffffu, send, O);
  }
}

__device__ __forceinline__ float warp_sum_scatter(float (&v)[32], int lane) {
  halve<16>(v, lane);
  halve<8>(v, lane);
  halve<4>(v, lane);
  halve<2>(v, lane);
  halve<1>(v, lane);
  return v[0];
}

__global__ void __launch_bounds__(kBlockSize)
    raster_backward_kernel(const int2* __restrict__ ranges, const int32_t* __restrict__ ids,
                           const PixelTri<float>* __restrict__ tris, const TriRect* __restrict__ rects, ViewParams vp,
                           BackwardImages in,
                           float* __restrict__ tri_grads) {
  __shared__ PixelTri<float> sh_tri[kBlockSize];
  __shared__ int32_t sh_id[kBlockSize];
  __shared__ TriRect sh_rect[kBlockSize];
  __shared__ int sh_max_last;
  const int tid = threadIdx.y * kTileSize + threadIdx.x, lane = tid & 31;
  const int x = blockIdx.x * kTileSize + threadIdx.x, y = blockIdx.y * kTileSize + threadIdx.y;
  const int wx0 = blockIdx.x * kTileSize, wy0 = blockIdx.y * kTileSize + (tid >> 5) * kWarpRows;
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
  const int end = sh_max_last;  // entries [0, end) of the tile list matter to some pixel of the tile
  const int warp_end = __reduce_max_sync(0xffffffffu, my_last);  // ... and [0, warp_end) to this warp
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
      sh_rect[tid] = rects[id];
    }
    __syncthreads();
    uint64_t todo = warp_batch_mask(sh_rect, min(top, warp_end) - lo, wx0, wy0, lane);
    while (todo != 0) {  // back to front: highest bit first; j is the same in every lane
      const int j = 63 - __clzll((long long)todo);
      todo &= ~(1ull << j);
      const int rank = lo + j;
      const PixelTri<float>& t = sh_tri[j];
      // This pixel's TriGrad of triangle j (zero when it does not contribute),
      // padded to 32 for the warp reduction below.
      float g[32];
#pragma unroll
      for (int c = 0; c < 32; ++c) g[c] = 0.f;
      bool contributes = false;
      const TriRect r = sh_rect[j];
      if (inside && rank < my_last && x >= r.x0 && x < r.x1 && y >= r.y0 && y < r.y1) {
        Fragment<float> f;
        shade(t, px, py, rx, ry, vp.k, f);
        if (f.alpha >= vp.k.alpha_min && f.alpha > 0.f) {
          contributes = true;
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
#pragma unroll
          for (int c = 0; c < 3; ++c) {
            g[kGColor + c] = w * G[c];
            g[kGNormal + c] = w * G[4 + c];
          }
          const float g_z = w * G[3];
          if (f.zclamp == 0) {
            const float g_invz = -g_z * f.z * f.z;
            g[kGH] = g_invz * rx;
            g[kGH + 1] = g_invz * ry;
            g[kGH + 2] = g_invz;
          } else if (f.zclamp < 0) {
            g[kGZlo] = g_z;
          } else {
            g[kGZhi] = g_z;
          }
          if (t.opacity * f.I < vp.k.alpha_max) {
            g[kGOpacity] = g_alpha * f.I;
            float gu[3];
            window_backward(f.u, t.sigma, vp.k.eps, vp.k.window, f.I, g_alpha * t.opacity, gu, g[kGSigma]);
#pragma unroll
            for (int i = 0; i < 3; ++i) {
              g[kGN + 2 * i] = gu[i] * (px - t.sx);
              g[kGN + 2 * i + 1] = gu[i] * (py - t.sy);
              g[kGS] -= gu[i] * t.nx[i];
              g[kGS + 1] -= gu[i] * t.ny[i];
            }
          }
        }
      }
      if (!__any_sync(0xffffffffu, contributes)) continue;  // warp-uniform
      // Sum over the warp; lane c then holds field c. One reduction instruction
      // for the warp's 21 fields instead of one per (pixel, field): a triangle
      // covers a few pixels of a warp, all adding to the same 21 addresses.
      const float sum = warp_sum_scatter(g, lane);
      if (lane < kTriGradSize && sum != 0.f) atomicAdd(tri_grads + (int64_t)kTriGradSize * sh_id[j] + lane, sum);
    }
  }
}

}  // namespace

void launch_raster_backward(const int2* ranges, const int32_t* ids, const PixelTri<float>* tris,
                            const TriRect* rects, const ViewParams& vp, const BackwardImages& in, float* tri_grads, cudaStream_t stream) {
  const dim3 grid(vp.tiles_x, vp.tiles_y), block(kTileSize, kTileSize);
  raster_backward_kernel<<<grid, block, 0, stream>>>(ranges, ids, tris, rects, vp, in, tri_grads);
}

}  // namespace flat::render::cuda
