// Backward compositing: one block per 8x8 tile, one thread per pixel; the
// tile's triangles are staged back to front in batches of 32, each batch in
// three phases (as the forward, render/cuda/raster_forward.cu):
//   coverage  the batch's (triangle, pixel) candidates, flattened over the
//             block (render/cuda/tile_candidates.cuh), evaluate the window
//             once where the fragment lies before the pixel's last blended
//             entry; where it contributed in the forward (alpha >= alpha_min)
//             they mark the pixel's 32-bit mask and the triangle's 64-bit
//             pixel mask, and keep the window value in shared memory;
//   replay    each pixel walks its marked triangles back to front with the
//             3DGS-style recurrence (as render/cpu/raster_cpu.cpp) and leaves
//             each fragment's blending weight and dL/dalpha in shared memory;
//   gradients two threads per triangle take alternate pixels of its mask and
//             sum its screen gradients (TriGrad, 21 fields) in registers, then
//             add them to global memory once per (triangle, tile) with 16-byte
//             atomics (rows padded to kTriGradStride floats).
// The window is evaluated once per fragment; the replay and the gradients
// reuse its value (recomputing only the cheap affine u_i and the depth).
#include "render/cuda/raster_kernels.h"
#include "render/cuda/tile_pixel.cuh"
#include "render/cuda/shared_tris.cuh"
#include "render/cuda/tile_candidates.cuh"

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

// The fragment of staged triangle t at pixel centre (px, py) with ray (rx, ry),
// from its kept window value I (bit-identical to shade() + fragment_depth()).
__device__ __forceinline__ Fragment<float> kept_fragment(const PixelTri<float>& t, float I, float px, float py,
                                                         float rx, float ry, const RasterConstants& k) {
  Fragment<float> f;
  const float dx = px - t.sx, dy = py - t.sy;
#pragma unroll
  for (int i = 0; i < 3; ++i) f.u[i] = 1.f + t.nx[i] * dx + t.ny[i] * dy;
  f.I = I;
  f.alpha = tmin(k.alpha_max, t.opacity * I);
  fragment_depth(t, rx, ry, f);
  return f;
}

__global__ void __launch_bounds__(kBlockSize)
    raster_backward_kernel(const int2* __restrict__ ranges, const int32_t* __restrict__ ids,
                           const PixelTri<float>* __restrict__ tris, const TriRect* __restrict__ rects, ViewParams vp,
                           BackwardImages in, float* __restrict__ tri_grads) {
  __shared__ SharedTris<kBatch> sh_tri;
  __shared__ TileBox sh_box[kBatch];
  __shared__ int sh_count[kBatch];                   // candidates of staged triangle j
  __shared__ int sh_start[kBatch + 1];               // candidates of triangle j: [sh_start[j], sh_start[j + 1])
  __shared__ int32_t sh_k[kBatch];                   // visible-list index (row of tri_grads)
  __shared__ unsigned long long sh_tri_hits[kBatch];  // per staged triangle: tile pixels it blends
  __shared__ unsigned int sh_hits[kBlockSize];       // per pixel: staged triangles it blends
  __shared__ int sh_last[kBlockSize];                // per pixel: number of list entries it blended through
  __shared__ float sh_G[kCh][kBlockSize];            // per pixel: upstream gradients
  __shared__ float sh_w[kBatch][kBlockSize];         // per (triangle, pixel) fragment: alpha T
  __shared__ float sh_ga[kBatch][kBlockSize];        //   and dL/dalpha
  // The window value of each marked fragment; after the gradient loop the
  // same memory takes the odd-half partial sums.
  __shared__ union {
    float I[kBatch][kBlockSize];
    float part[kBatch][kTriGradSize];
  } sh_u;
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
  const int j_own = pix.tid % kBatch, half = pix.tid / kBatch;  // this thread's triangle and share in phase 3
  for (int top = end; top > 0; top -= kBatch) {
    const int lo = max(0, top - kBatch), batch = top - lo;  // stage entries [lo, top)
    __syncthreads();
    int count = 0;
    if (pix.tid < batch) {
      const int32_t k = ids[range.x + lo + pix.tid];
      sh_k[pix.tid] = k;
      sh_tri.put(pix.tid, tris[k]);
      sh_box[pix.tid] = tile_box(rects[k], pix.tx0, pix.ty0, count);  // rects are clipped to the image
      sh_tri_hits[pix.tid] = 0ull;
    }
    if (pix.tid < 32) {  // warp 0 wrote the counts: a warp barrier suffices
      sh_count[pix.tid] = count;
      __syncwarp();
      scan_candidate_counts<kBatch>(pix.tid, sh_count, sh_start);
    }
    sh_hits[pix.tid] = 0u;
    __syncthreads();
    // Phase 1, coverage.
    const int candidates = sh_start[kBatch];
    for (int i = pix.tid; i < candidates; i += kBlockSize) {
      int j, q;
      candidate<kBatch>(i, sh_start, sh_box, j, q);
      if (lo + j >= sh_last[q]) continue;  // after the pixel's last blended entry
      const PixelTri<float> t = sh_tri.get(j);
      Fragment<float> f;
      shade(t, pix.tx0 + (q % kTileSize) + 0.5f, pix.ty0 + (q / kTileSize) + 0.5f, 0.f, 0.f, vp.k, f);
      if (f.alpha >= vp.k.alpha_min && f.alpha > 0.f) {
        sh_u.I[j][q] = f.I;
        atomicOr(&sh_hits[q], 1u << j);
        atomicOr(&sh_tri_hits[j], 1ull << q);
      }
    }
    __syncthreads();
    // Phase 2, replay back to front (highest bit first).
    for (unsigned int m = sh_hits[pix.tid]; m != 0u;) {
      const int j = 31 - __clz(m);
      m &= ~(1u << j);
      const PixelTri<float> t = sh_tri.get(j);
      const Fragment<float> f = kept_fragment(t, sh_u.I[j][pix.tid], pix.px, pix.py, pix.rx, pix.ry, vp.k);
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
    // Phase 3, per-triangle gradients: the two threads of triangle j_own take
    // alternate pixels of its mask.
    float g[kTriGradStride];  // TriGrad's fields, then zeros up to the padded row
#pragma unroll
    for (int c = 0; c < kTriGradStride; ++c) g[c] = 0.f;
    const bool own = j_own < batch;
    const unsigned long long mine = own ? sh_tri_hits[j_own] : 0ull;
    int n = 0;
    if (own) {
      const PixelTri<float> t = sh_tri.get(j_own);
      for (unsigned long long m = mine; m != 0ull; m &= m - 1ull, ++n) {
        if ((n & 1) != half) continue;
        const int q = __ffsll((long long)m) - 1;
        const float qx = pix.tx0 + (q % kTileSize) + 0.5f, qy = pix.ty0 + (q / kTileSize) + 0.5f;
        const float2 qr = pixel_ray(vp, qx, qy);  // bit-identical to that pixel's own ray in phase 2
        const Fragment<float> f = kept_fragment(t, sh_u.I[j_own][q], qx, qy, qr.x, qr.y, vp.k);
        float Gq[kCh];
#pragma unroll
        for (int c = 0; c < kCh; ++c) Gq[c] = sh_G[c][q];
        add_fragment_grads(t, f, qx, qy, qr.x, qr.y, sh_w[j_own][q], sh_ga[j_own][q], Gq, vp.k, g);
      }
    }
    // The second half hands its sums to the first, which adds them to global
    // memory: 16-byte atomics over the padded row.
    const bool second_any = __syncthreads_or(half == 1 && n > 1);
    if (half == 1 && own && second_any) {
#pragma unroll
      for (int c = 0; c < kTriGradSize; ++c) sh_u.part[j_own][c] = g[c];
    }
    __syncthreads();
    if (half == 0 && own && mine != 0ull) {
      if (second_any) {
#pragma unroll
        for (int c = 0; c < kTriGradSize; ++c) g[c] += sh_u.part[j_own][c];
      }
      float4* dst = reinterpret_cast<float4*>(tri_grads + (int64_t)kTriGradStride * sh_k[j_own]);
#pragma unroll
      for (int v = 0; v < kTriGradStride / 4; ++v) {
        const int c = 4 * v;
        const float4 a = make_float4(g[c], g[c + 1], g[c + 2], g[c + 3]);
        if (a.x != 0.f || a.y != 0.f || a.z != 0.f || a.w != 0.f) atomicAdd(dst + v, a);
      }
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
