// Backward compositing: one block per 8x8 tile, one thread per pixel, and
// each of the block's two warps replays the tile's list for its own 8x4 half
// (render/cuda/tile_pixel.cuh) on its own, as the forward does
// (render/cuda/raster_forward.cu). Back to front, a round stages the last 16
// entries of the next 32 whose forward coverage mask (PairMasks,
// raster_kernels.h) is not empty (the masks and pair ids of the 32 entries
// below are read a round ahead), in two phases:
//   replay    each pixel walks the staged triangles its mask bits name and
//             that lie before its last blended entry, back to front, with the
//             3DGS-style recurrence (as render/cpu/raster_cpu.cpp); it
//             evaluates each fragment's window and depth and leaves the
//             window value, depth, blending weight and dL/dalpha in shared
//             memory;
//   gradients two lanes per triangle take alternate pixels of its mask and
//             sum its screen gradients (TriGrad's 18 fields and the normal's
//             3) in registers, add the two halves with a shuffle, fold the
//             normal's into the plane's and add the row to global memory once
//             per (triangle, region) with 16-byte atomics (rows padded to
//             kTriGradStride floats).
// The forward's masks spare the backward its own coverage test: no support
// rectangles are read, and the window is evaluated only where a fragment
// blended; the gradients reuse its value and depth (recomputing only the
// cheap affine u_i).
// Rounds of 16 triangles, not 32: the per-fragment arrays (weight, dL/dalpha,
// window value, depth) are most of a warp's shared memory, and halving them
// lets twice as many warps share an SM (21.9 KB a block: 10 blocks fit).
#include "render/cuda/raster_kernels.h"
#include "render/cuda/tile_pixel.cuh"
#include "render/cuda/shared_tris.cuh"

namespace flat::render::cuda {
namespace {

constexpr int kBatch = 16;  // staged triangles per round: two lanes each in phase 3
constexpr int kCh = 8;      // r, g, b, depth, nx, ny, nz, alpha
constexpr int kWarps = kBlockSize / 32;
static_assert(2 * kBatch == 32, "two lanes per staged triangle");
static_assert(kCh == 8, "upstream gradients staged as two float4");
// Offsets of the TriGrad fields in a flat float array (layout of TriGrad<float>),
// then the normal's gradient, summed beside them and folded into h
// (fold_normal_grad()) before the row is added.
constexpr int kGS = 0, kGN = 2, kGH = 8, kGZlo = 11, kGZhi = 12, kGColor = 13, kGOpacity = 16, kGSigma = 17,
              kGNormal = kTriGradSize, kGAcc = kTriGradSize + 3;

// Adds fragment f's contribution to triangle t's screen gradients g, given the
// fragment's weight w = alpha T, dL/dalpha and the pixel's upstream gradients G.
__device__ __forceinline__ void add_fragment_grads(const PixelTri<float>& t, const Fragment<float>& f, float px,
                                                   float py, float rx, float ry, float w, float g_alpha,
                                                   const float G[kCh], const RasterConstants& k,
                                                   float g[kGAcc]) {
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

// A fragment's depth as the replay keeps it for the gradients: z where the
// ray meets the plane, or a negative code where it was clamped (the
// gradient then needs only which end).
constexpr float kKeptZlo = -1.f, kKeptZhi = -2.f;
__device__ __forceinline__ float kept_depth(const Fragment<float>& f) {
  return f.zclamp == 0 ? f.z : (f.zclamp < 0 ? kKeptZlo : kKeptZhi);
}

// The fragment of staged triangle t at pixel centre (px, py) from its kept
// window value I and depth (bit-identical to shade() + fragment_depth()).
__device__ __forceinline__ Fragment<float> kept_fragment(const PixelTri<float>& t, float I, float z, float px,
                                                         float py, const RasterConstants& k) {
  Fragment<float> f;
  const float dx = px - t.sx, dy = py - t.sy;
#pragma unroll
  for (int i = 0; i < 3; ++i) f.u[i] = 1.f + t.nx[i] * dx + t.ny[i] * dy;
  f.I = I;
  f.alpha = tmin(k.alpha_max, t.opacity * I);
  f.z = z;
  f.zclamp = z > 0.f ? 0 : (z == kKeptZlo ? -1 : 1);
  return f;
}

struct WarpStage {  // one warp's staged triangles (slot j), per-pixel and per-fragment values
  SharedTris<kBatch> tri;
  int pos[kBatch];             // position in the tile's list
  int32_t k[kBatch];           // visible-list index (row of tri_grads)
  unsigned int pixels[kBatch];  // region pixels of the slot's forward coverage mask
  float4 G[kCh / 4][32];       // per pixel: upstream gradients (two 128-bit loads in phase 3)
  float I[kBatch][32];         // per (slot, pixel) fragment: window value,
  float z[kBatch][32];         //   depth (kept_depth()),
  float w[kBatch][32];         //   alpha T,
  float ga[kBatch][32];        //   and dL/dalpha
};

// Occupancy: 10 blocks of two warps per SM. That takes at most 96 registers
// and the largest shared-memory carveout; the compiler's 104 registers and
// the default carveout allowed 8.
__global__ void __launch_bounds__(kBlockSize, 10)
    raster_backward_kernel(const int2* __restrict__ ranges, const int32_t* __restrict__ tile_order,
                           const int32_t* __restrict__ ids, const PixelTri<float>* __restrict__ tris, ViewParams vp,
                           GroupRays rays, BackwardImages in, float* __restrict__ tri_grads) {
  __shared__ WarpStage stage[kWarps];
  const TilePixel pix = tile_pixel(vp, rays, tile_order);
  WarpStage& sh = stage[pix.warp];
  const int lane = pix.lane;
  const int2 range = ranges[pix.list];
  const uint32_t* __restrict__ masks = in.masks.bits + pix.warp * in.masks.pairs + range.x;
  const int64_t HW = (int64_t)vp.width * vp.height, p = pix.view * HW + (int64_t)pix.y * vp.width + pix.x;
  const int64_t p3 = 2 * pix.view * HW + p;  // three channels a view
  float G[kCh] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f};
  float T = 1.f, t_final = 1.f;
  int my_last = 0;
  if (pix.inside) {
    for (int c = 0; c < 3; ++c) G[c] = in.g_rgb[c * HW + p3], G[4 + c] = in.g_normal[c * HW + p3];
    G[3] = in.g_depth[p];
    G[7] = in.g_alpha[p];
    t_final = T = in.t_final[p];
    my_last = in.last[p];
  }
#pragma unroll
  for (int c = 0; c < kCh; c += 4) sh.G[c / 4][lane] = make_float4(G[c], G[c + 1], G[c + 2], G[c + 3]);
  // dL/dT_final through the background, times T_final (one register, not two).
  const float bg_t = t_final * (vp.background[0] * G[0] + vp.background[1] * G[1] + vp.background[2] * G[2]);
  // The replay's running sums enter dL/dalpha only through their dot product
  // with G, so it keeps that product (acc_G) and the last fragment's (last_G)
  // instead of the 8 channels of each (the CPU reference keeps the channels).
  float acc_G = 0.f, last_G = 0.f, last_alpha = 0.f;
  const int j_own = lane % kBatch, half = lane / kBatch;  // this lane's slot and share in phase 3
  // List entries [0, top) remain; entries from the region's furthest last
  // blended one on matter to none of its pixels (and the forward wrote the
  // masks of all entries before it). A round looks at the window
  // [top - 32, top); the masks and pair ids of the window before it,
  // [top - 64, top - 32), are read a round ahead (read at the round's start,
  // their loads were 10% of the stall samples), and the next round's window,
  // which lies in these two, comes from registers.
  int top = __reduce_max_sync(kFullWarp, my_last);
  unsigned cur_pixels, ahead_pixels;
  int cur_id, ahead_id;
  auto read_entry = [&](int e, unsigned& pixels, int& id) {
    pixels = 0u;
    id = 0;
    if (e >= 0) {
      pixels = masks[e];
      id = ids[range.x + e];
    }
  };
  read_entry(top - 32 + lane, cur_pixels, cur_id);
  read_entry(top - 64 + lane, ahead_pixels, ahead_id);
  while (top > 0) {
    // Stage the last kBatch entries of [top - 32, top) that cover a pixel of this region.
    const int e = top - 32 + lane;
    const unsigned pixels = cur_pixels;
    const int k = pair_index(cur_id);  // pair id (raster_kernels.h)
    const bool covers = pixels != 0u;
    const unsigned touching = __ballot_sync(kFullWarp, covers);
    const int n_touching = __popc(touching);
    const int above = __popc(touching & ~lanes_below(lane) & ~(1u << lane));  // touching entries after e
    const bool taken = covers && above < kBatch;
    const int batch = min(n_touching, kBatch), slot = batch - 1 - above;
    // The next round ends after the highest touching entry not taken (if any).
    const int next = __reduce_max_sync(kFullWarp, covers && above == kBatch ? e + 1 : 0);
    const int next_top = n_touching > kBatch ? next : top - 32;
    {  // entry next_top - 32 + lane: in this window (lane from_cur) or the one ahead
      const int from_cur = next_top - top + lane, from_ahead = from_cur + 32;
      const unsigned p_cur = __shfl_sync(kFullWarp, cur_pixels, from_cur & 31);
      const int i_cur = __shfl_sync(kFullWarp, cur_id, from_cur & 31);
      const unsigned p_ahead = __shfl_sync(kFullWarp, ahead_pixels, from_ahead & 31);
      const int i_ahead = __shfl_sync(kFullWarp, ahead_id, from_ahead & 31);
      cur_pixels = from_cur >= 0 ? p_cur : p_ahead;
      cur_id = from_cur >= 0 ? i_cur : i_ahead;
    }
    read_entry(next_top - 64 + lane, ahead_pixels, ahead_id);
    top = next_top;
    if (batch == 0) continue;
    if (taken) {
      sh.tri.put(slot, tris + k);
      sh.pos[slot] = e;
      sh.k[slot] = k;
      sh.pixels[slot] = pixels;
    }
    __syncwarp();
    // This pixel's fragments: the slots that cover it, before its last
    // blended entry; and (mine) the pixels of slot j_own, for phase 3.
    unsigned hits = 0u, mine = 0u;
    for (int j = 0; j < batch; ++j) {
      const bool hit = ((sh.pixels[j] >> lane) & 1u) && sh.pos[j] < my_last;
      const unsigned m = __ballot_sync(kFullWarp, hit);
      hits |= (unsigned)hit << j;
      if (j == j_own) mine = m;
    }
    // Phase 1, replay back to front (highest slot first).
    for (unsigned m = hits; m != 0u;) {
      const int j = 31 - __clz(m);
      m &= ~(1u << j);
      const PixelTri<float> t = sh.tri.get(j);
      Fragment<float> f;
      shade(t, pix.px, pix.py, pix.rx, pix.ry, vp.k, f);
      fragment_depth(t, pix.rx, pix.ry, f);
      const float inv_keep = __fdividef(1.f, 1.f - f.alpha);
      T = T * inv_keep;
      const float fv[kCh] = {t.color[0], t.color[1], t.color[2], f.z, t.normal[0], t.normal[1], t.normal[2], 1.f};
      float fv_G = 0.f;
#pragma unroll
      for (int c = 0; c < kCh; ++c) fv_G += fv[c] * G[c];
      acc_G = last_alpha * last_G + (1.f - last_alpha) * acc_G;  // what lies behind, dotted with G
      const float g_alpha = fv_G - acc_G;
      last_G = fv_G;
      last_alpha = f.alpha;
      sh.I[j][lane] = f.I;
      sh.z[j][lane] = kept_depth(f);
      sh.w[j][lane] = f.alpha * T;
      sh.ga[j][lane] = g_alpha * T - inv_keep * bg_t;
    }
    __syncwarp();
    // Phase 2, per-triangle gradients: the two lanes of slot j_own take
    // alternate pixels of its mask, then add up through a shuffle.
    float g[kGAcc];  // TriGrad's fields, then the normal's gradient
#pragma unroll
    for (int c = 0; c < kGAcc; ++c) g[c] = 0.f;
    if (mine != 0u) {
      const PixelTri<float> t = sh.tri.get(j_own);
      // Alternate pixels: lane half 1 starts at the second; each step clears two.
      for (unsigned m = half ? mine & (mine - 1u) : mine; m != 0u; m &= m - 1u, m &= m - 1u) {
        const int q = __ffs(m) - 1;
        const float2 c = region_pixel(pix, q);
        const float2 qr = pixel_ray(rays, pix.view, c.x, c.y);  // bit-identical to that pixel's own ray in phase 1
        const Fragment<float> f = kept_fragment(t, sh.I[j_own][q], sh.z[j_own][q], c.x, c.y, vp.k);
        const float4 g0 = sh.G[0][q], g1 = sh.G[1][q];
        const float Gq[kCh] = {g0.x, g0.y, g0.z, g0.w, g1.x, g1.y, g1.z, g1.w};
        add_fragment_grads(t, f, c.x, c.y, qr.x, qr.y, sh.w[j_own][q], sh.ga[j_own][q], Gq, vp.k, g);
      }
    }
    if (__any_sync(kFullWarp, half == 1 && __popc(mine) > 1)) {
#pragma unroll
      for (int c = 0; c < kGAcc; ++c) g[c] += __shfl_down_sync(kFullWarp, g[c], kBatch);
    }
    if (half == 0 && mine != 0u) {  // 16-byte atomics over the padded row
      fold_normal_grad(sh.tri.get(j_own).h, g + kGNormal, g + kGH);
      float4* dst = reinterpret_cast<float4*>(tri_grads + (int64_t)kTriGradStride * sh.k[j_own]);
      auto field = [&](int c) { return c < kTriGradSize ? g[c] : 0.f; };  // zeros in the padding
#pragma unroll
      for (int v = 0; v < kTriGradStride / 4; ++v) {
        const int c = 4 * v;
        const float4 a = make_float4(field(c), field(c + 1), field(c + 2), field(c + 3));
        if (a.x != 0.f || a.y != 0.f || a.z != 0.f || a.w != 0.f) atomicAdd(dst + v, a);
      }
    }
    __syncwarp();  // this round's reads of the stage before the next round's writes
  }
}

}  // namespace

void launch_raster_backward(const int2* ranges, const int32_t* tile_order, const int32_t* ids,
                            const PixelTri<float>* tris, const ViewParams& vp, const GroupRays& rays,
                            const BackwardImages& in, float* tri_grads, cudaStream_t stream) {
  // Only the backward: the forward's gathers need the L1 that a larger
  // shared-memory carveout takes away (measured: forward 16.7 -> 24.1 ms).
  cudaFuncSetAttribute(raster_backward_kernel, cudaFuncAttributePreferredSharedMemoryCarveout,
                       cudaSharedmemCarveoutMaxShared);
  const dim3 grid(rays.views * vp.tiles_x * vp.tiles_y), block(kTileSize, kTileSize);
  raster_backward_kernel<<<grid, block, 0, stream>>>(ranges, tile_order, ids, tris, vp, rays, in, tri_grads);
}

}  // namespace flat::render::cuda
