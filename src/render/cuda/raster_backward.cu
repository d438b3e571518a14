// Backward compositing: one block per 8x8 tile, one thread per pixel; the
// tile's triangles are staged back to front in batches of 32, each batch in
// three phases (as the forward, render/cuda/raster_forward.cu):
//   coverage  two threads per staged triangle (even / odd rows) evaluate it
//             on its pixels of the tile and mark each pixel's 32-bit mask
//             where it contributed in the forward (alpha >= alpha_min, before
//             the pixel's last contributor);
//   replay    each pixel walks its marked triangles back to front with the
//             3DGS-style recurrence (as render/cpu/raster_cpu.cpp) and leaves
//             each fragment's blending weight and dL/dalpha in shared memory;
//   gradients the two threads of a triangle sum its screen gradients
//             (TriGrad, 21 fields) over its marked pixels in registers, and
//             add them to global memory once per (triangle, tile).
// No warp-wide reduction and no lane idles on a triangle that misses its pixel.
#include "render/cuda/raster_kernels.h"
#include "render/cuda/tile_pixel.cuh"
#include "render/cuda/shared_tris.cuh"

namespace flat::render::cuda {
namespace {

constexpr int kBatch = 32;  // staged triangles per batch: one 32-bit mask per pixel
constexpr int kCh = 8;      // r, g, b, depth, nx, ny, nz, alpha
static_assert(kBlockSize == 2 * kBatch, "two threads per staged triangle");
// Offsets of the TriGrad fields in a flat float array (layout of TriGrad<float>).
constexpr int kGS = 0, kGN = 2, kGH = 8, kGZlo = 11, kGZhi = 12, kGNormal = 13, kGColor = 16, kGOpacity = 19,
              kGSigma = 20;

// Adds fragment f's contribution to triangle t's screen gradients g, given the
// fragment's weight w = alpha T, dL/dalpha and the pixel's upstream gradients G.
__device__ __forceinline__ void add_fragment_grads(const PixelTri<float>& t, const Fragment<float>& f, float px,
                                                   float py, float rx, float ry, float w, float g_alpha,
                                                   const float G[kCh], const RasterConstants& k,
                                                   float g[kTriGradSize]) {
#pragma unroll
  for (int c = 0; c < 3; ++c) {
    g[kGColor + c] += w * G[c];
    g[kGNormal + c] += w * G[4 + c];
  }
  const float g_z = w * G[3];
  if (f.zclamp == 0) {
    const float g_invz = -g_z * f.z * f.z;
    g[kGH] += g_invz * rx;
    g[kGH + 1] += g_invz * ry;
    g[kGH + 2] += g_invz;
  } else if (f.zclamp < 0) {
    g[kGZlo] += g_z;
  } else {
    g[kGZhi] += g_z;
  }
  if (t.opacity * f.I < k.alpha_max) {  // alpha not capped: it depends on opacity and window
    g[kGOpacity] += g_alpha * f.I;
    float gu[3], g_sigma;
    window_backward(f.u, t.sigma, k.eps, k.window, f.I, g_alpha * t.opacity, gu, g_sigma);
    g[kGSigma] += g_sigma;
#pragma unroll
    for (int i = 0; i < 3; ++i) {
      g[kGN + 2 * i] += gu[i] * (px - t.sx);
      g[kGN + 2 * i + 1] += gu[i] * (py - t.sy);
      g[kGS] -= gu[i] * t.nx[i];
      g[kGS + 1] -= gu[i] * t.ny[i];
    }
  }
}

__global__ void __launch_bounds__(kBlockSize)
    raster_backward_kernel(const int2* __restrict__ ranges, const int32_t* __restrict__ ids,
                           const PixelTri<float>* __restrict__ tris, const TriRect* __restrict__ rects, ViewParams vp,
                           BackwardImages in, float* __restrict__ tri_grads) {
  __shared__ SharedTris<kBatch> sh_tri;
  __shared__ TriRect sh_rect[kBatch];
  __shared__ int32_t sh_k[kBatch];              // visible-list index (row of tri_grads)
  __shared__ unsigned int sh_hits[kBlockSize];  // per pixel: staged triangles it blends
  __shared__ int sh_last[kBlockSize];           // per pixel: number of list entries it blended through
  __shared__ float sh_G[kCh][kBlockSize];       // per pixel: upstream gradients
  __shared__ float sh_w[kBatch][kBlockSize];    // per (triangle, pixel) fragment: alpha T
  __shared__ float sh_ga[kBatch][kBlockSize];   //   and dL/dalpha
  __shared__ float sh_part[kBatch][kTriGradSize];  // odd-row partial sums
  __shared__ int sh_end;
  const TilePixel pix = tile_pixel(vp);
  const int2 range = ranges[blockIdx.y * vp.tiles_x + blockIdx.x];
  const int64_t HW = (int64_t)vp.width * vp.height, p = (int64_t)pix.y * vp.width + pix.x;
  float G[kCh] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f};
  float T = 1.f, t_final = 1.f;
  int my_last = 0;
  if (pix.inside) {
    for (int c = 0; c < 3; ++c) G[c] = in.g_rgb[c * HW + p], G[4 + c] = in.g_normal[c * HW + p];
    G[3] = in.g_depth[p];
    G[7] = in.g_alpha[p];
    t_final = T = in.t_final[p];
    my_last = in.last[p];
  }
#pragma unroll
  for (int c = 0; c < kCh; ++c) sh_G[c][pix.tid] = G[c];
  sh_last[pix.tid] = my_last;
  if (pix.tid == 0) sh_end = 0;
  __syncthreads();
  atomicMax(&sh_end, my_last);
  __syncthreads();
  const int end = sh_end;  // entries [0, end) of the tile list matter to some pixel of the tile
  const float bgdot = vp.background[0] * G[0] + vp.background[1] * G[1] + vp.background[2] * G[2];
  float acc[kCh] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f}, last_f[kCh] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f};
  float last_alpha = 0.f;
  const int j_own = pix.tid % kBatch, row_parity = pix.tid / kBatch;  // this thread's triangle and rows in phases 1 and 3
  for (int top = end; top > 0; top -= kBatch) {
    const int lo = max(0, top - kBatch), batch = top - lo;  // stage entries [lo, top)
    __syncthreads();
    if (pix.tid < batch) {
      const int32_t k = ids[range.x + lo + pix.tid];
      sh_k[pix.tid] = k;
      sh_tri.put(pix.tid, tris[k]);
      sh_rect[pix.tid] = rects[k];
    }
    sh_hits[pix.tid] = 0u;
    __syncthreads();
    // Phase 1, coverage.
    const bool own = j_own < batch;
    int xa = 0, xb = 0, ya = 0, yb = 0;
    if (own) {
      const TriRect r = sh_rect[j_own];  // already clipped to the image
      xa = max(r.x0, pix.tx0), xb = min(r.x1, pix.tx0 + kTileSize);
      ya = max(r.y0, pix.ty0), yb = min(r.y1, pix.ty0 + kTileSize);
      ya += (ya - pix.ty0 + row_parity) & 1;  // first row of this thread's parity
      const PixelTri<float> t = sh_tri.get(j_own);
      for (int yy = ya; yy < yb; yy += 2)
        for (int xx = xa; xx < xb; ++xx) {
          const int q = (yy - pix.ty0) * kTileSize + (xx - pix.tx0);
          if (lo + j_own >= sh_last[q]) continue;  // after the pixel's last blended entry
          Fragment<float> f;
          shade(t, xx + 0.5f, yy + 0.5f, 0.f, 0.f, vp.k, f);  // alpha only: the ray is not used
          if (f.alpha >= vp.k.alpha_min && f.alpha > 0.f) atomicOr(&sh_hits[q], 1u << j_own);
        }
    }
    __syncthreads();
    // Phase 2, replay back to front (highest bit first).
    for (unsigned int m = sh_hits[pix.tid]; m != 0u;) {
      const int j = 31 - __clz(m);
      m &= ~(1u << j);
      const PixelTri<float> t = sh_tri.get(j);
      Fragment<float> f;
      shade(t, pix.px, pix.py, pix.rx, pix.ry, vp.k, f);
      fragment_depth(t, pix.rx, pix.ry, f);
      const float inv_keep = __fdividef(1.f, 1.f - f.alpha);
      T = T * inv_keep;
      const float fv[kCh] = {t.color[0], t.color[1], t.color[2], f.z, t.normal[0], t.normal[1], t.normal[2], 1.f};
      float g_alpha = 0.f;
#pragma unroll
      for (int c = 0; c < kCh; ++c) {
        acc[c] = last_alpha * last_f[c] + (1.f - last_alpha) * acc[c];
        g_alpha += (fv[c] - acc[c]) * G[c];
        last_f[c] = fv[c];
      }
      last_alpha = f.alpha;
      sh_w[j][pix.tid] = f.alpha * T;
      sh_ga[j][pix.tid] = g_alpha * T - t_final * inv_keep * bgdot;
    }
    __syncthreads();
    // Phase 3, per-triangle gradients over its marked pixels.
    float g[kTriGradSize];
#pragma unroll
    for (int c = 0; c < kTriGradSize; ++c) g[c] = 0.f;
    bool any = false;
    if (own) {
      const PixelTri<float> t = sh_tri.get(j_own);
      for (int yy = ya; yy < yb; yy += 2)
        for (int xx = xa; xx < xb; ++xx) {
          const int q = (yy - pix.ty0) * kTileSize + (xx - pix.tx0);
          if (!((sh_hits[q] >> j_own) & 1u)) continue;
          any = true;
          const float qx = xx + 0.5f, qy = yy + 0.5f;
          const float2 qr = pixel_ray(vp, qx, qy);  // bit-identical to that pixel's own ray in phase 2
          Fragment<float> f;
          shade(t, qx, qy, qr.x, qr.y, vp.k, f);
          fragment_depth(t, qr.x, qr.y, f);
          float Gq[kCh];
#pragma unroll
          for (int c = 0; c < kCh; ++c) Gq[c] = sh_G[c][q];
          add_fragment_grads(t, f, qx, qy, qr.x, qr.y, sh_w[j_own][q], sh_ga[j_own][q], Gq, vp.k, g);
        }
    }
    // Odd rows hand their sums to the even-row thread of the same triangle,
    // which adds them to global memory (one reduction per field).
    const bool odd_any = __syncthreads_or(row_parity == 1 && any);
    if (row_parity == 1 && own && odd_any) {
#pragma unroll
      for (int c = 0; c < kTriGradSize; ++c) sh_part[j_own][c] = g[c];
    }
    __syncthreads();
    if (row_parity == 0 && own) {
      if (odd_any) {
#pragma unroll
        for (int c = 0; c < kTriGradSize; ++c) g[c] += sh_part[j_own][c];
      }
      float* dst = tri_grads + (int64_t)kTriGradSize * sh_k[j_own];
#pragma unroll
      for (int c = 0; c < kTriGradSize; ++c)
        if (g[c] != 0.f) atomicAdd(dst + c, g[c]);
    }
  }
}

}  // namespace

void launch_raster_backward(const int2* ranges, const int32_t* ids, const PixelTri<float>* tris,
                            const TriRect* rects, const ViewParams& vp, const BackwardImages& in, float* tri_grads,
                            cudaStream_t stream) {
  const dim3 grid(vp.tiles_x, vp.tiles_y), block(kTileSize, kTileSize);
  raster_backward_kernel<<<grid, block, 0, stream>>>(ranges, ids, tris, rects, vp, in, tri_grads);
}

}  // namespace flat::render::cuda
