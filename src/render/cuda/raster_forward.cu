// Forward compositing: one block per 8x8 tile, one thread per pixel; the
// tile's depth-sorted triangles are staged in shared memory in batches of 64,
// and each warp visits only those that can touch its pixels
// (render/cuda/warp_mask.cuh). Same per-pixel semantics as
// render/cpu/raster_cpu.cpp.
#include "render/cuda/raster_kernels.h"
#include "render/cuda/warp_mask.cuh"

namespace flat::render::cuda {
namespace {

__global__ void __launch_bounds__(kBlockSize)
    raster_forward_kernel(const int2* __restrict__ ranges, const int32_t* __restrict__ ids,
                          const PixelTri<float>* __restrict__ tris, const TriRect* __restrict__ rects,
                          const int32_t* __restrict__ visible, ViewParams vp, ForwardImages out,
                          unsigned int* __restrict__ max_weight_bits) {
  __shared__ PixelTri<float> sh_tri[kBlockSize];
  __shared__ int32_t sh_id[kBlockSize];
  __shared__ TriRect sh_rect[kBlockSize];
  const int tid = threadIdx.y * kTileSize + threadIdx.x, lane = tid & 31;
  const int x = blockIdx.x * kTileSize + threadIdx.x, y = blockIdx.y * kTileSize + threadIdx.y;
  const int wx0 = blockIdx.x * kTileSize, wy0 = blockIdx.y * kTileSize + (tid >> 5) * kWarpRows;
  const bool inside = x < vp.width && y < vp.height;
  const float px = x + 0.5f, py = y + 0.5f;
  const float rx = (px - vp.cam.cx) / vp.cam.fx, ry = (py - vp.cam.cy) / vp.cam.fy;
  const int2 range = ranges[blockIdx.y * vp.tiles_x + blockIdx.x];
  const int total = range.y - range.x;
  bool done = !inside;
  float T = 1.f, acc[7] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f}, median = 0.f;
  int last = 0;
  for (int base = 0; base < total; base += kBlockSize) {
    if (__syncthreads_count(done) == kBlockSize) break;
    const int idx = range.x + base + tid;
    if (idx < range.y) {
      const int32_t id = ids[idx];
      sh_id[tid] = visible[id];
      sh_tri[tid] = tris[id];
      sh_rect[tid] = rects[id];
    }
    __syncthreads();
    const int batch = min(kBlockSize, total - base);
    uint64_t todo = __all_sync(0xffffffffu, done) ? 0 : warp_batch_mask(sh_rect, batch, wx0, wy0, lane);
    while (todo != 0) {  // front to back: lowest bit first
      const int j = __ffsll((long long)todo) - 1;
      todo &= todo - 1;
      float w = 0.f;
      const TriRect r = sh_rect[j];
      // The pixel support rectangle first (as the CPU reference, which shades
      // only those pixels): a warp whose pixels all lie outside skips the window.
      if (!done && x >= r.x0 && x < r.x1 && y >= r.y0 && y < r.y1) {
        const PixelTri<float>& t = sh_tri[j];
        Fragment<float> f;
        shade(t, px, py, rx, ry, vp.k, f);
        if (f.alpha >= vp.k.alpha_min && f.alpha > 0.f) {
          const float test_T = T * (1.f - f.alpha);
          if (test_T < vp.k.t_min) {
            done = true;
          } else {
            fragment_depth(t, rx, ry, f);
            w = f.alpha * T;
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
          }
        }
      }
      // Per-triangle maximum blending weight (non-negative floats order as
      // their bits). j is the same in every lane, so the warp takes the
      // maximum first (one redux) and one lane issues the atomic.
      const unsigned int wmax = __reduce_max_sync(0xffffffffu, w > 0.f ? __float_as_uint(w) : 0u);
      if (lane == 0 && wmax != 0u) atomicMax(&max_weight_bits[sh_id[j]], wmax);
    }
    __syncthreads();
  }
  if (!inside) return;
  const int64_t HW = (int64_t)vp.width * vp.height, p = (int64_t)y * vp.width + x;
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
