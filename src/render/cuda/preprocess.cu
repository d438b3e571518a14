// Per-(view, triangle) preprocessing, in two passes (the maths is
// flat/render/shared/triangle_math.h, shared with the CPU reference; its chain rule is
// render/cuda/preprocess_backward.cu):
//   cull    all N triangles: support rectangle, tiles touched (0 = culled) and
//           depth sort key; cheap outputs, coalesced; and their sum, the
//           view's pair count (one atomic a block).
//   screen  the view's visible triangles only (typically a quarter of them):
//           the PixelTri screen data the compositing kernels read, stored
//           compactly (index k of the visible list). The backward re-runs it
//           from the stored visible list instead of keeping it.
// Every array of several floats per triangle is moved through shared memory
// (render/cuda/row_staging.cuh).
#include "flat/render/shared/block_sum.cuh"
#include "render/cuda/raster_kernels.h"
#include "render/cuda/row_staging.cuh"

namespace flat::render::cuda {
namespace {

constexpr int kThreads = 128;
constexpr int kTriFloats = sizeof(PixelTri<float>) / sizeof(float);  // 24 (23 + alignment padding)
constexpr int kTriStride = kTriFloats + 1;

__global__ void __launch_bounds__(kThreads)
    cull_kernel(const float* __restrict__ vertices, const float* __restrict__ opacities, int64_t n, ViewParams vp,
                TriRect* __restrict__ rects, int32_t* __restrict__ tile_counts, float* __restrict__ keys,
                unsigned long long* __restrict__ total) {
  __shared__ float sh_v[kThreads * 9];
  const int64_t base = (int64_t)blockIdx.x * kThreads;
  const int rows = (int)((n - base) < kThreads ? (n - base) : kThreads);
  load_rows<9, 9, kThreads>(vertices, nullptr, base, rows, sh_v);
  __syncthreads();
  int32_t count = 0;
  if ((int)threadIdx.x < rows) {
    const int64_t i = base + threadIdx.x;
    TriRect r;
    float key = 0.f;
    PixelTri<float> t;
    if (opacity_can_blend(opacities[i], vp.k) &&
        preprocess_forward(sh_v + 9 * threadIdx.x, vp.cam, vp.k, vp.width, vp.height, t, r, key))
      count = (tile_hi(r.x1) - tile_lo(r.x0)) * (tile_hi(r.y1) - tile_lo(r.y0));  // < 2^31: ints hold the tile grid
    tile_counts[i] = count;
    if (count > 0) {  // only visible triangles' rectangles and keys are read (and culling comes in runs)
      rects[i] = r;
      keys[i] = key;
    }
  }
  // The pair count, in 64 bits (it may pass 2^31: the host then fails clearly).
  add_block_sum<kThreads>(count, total);
}

__global__ void __launch_bounds__(kThreads)
    screen_kernel(const float* __restrict__ vertices, const float* __restrict__ colors,
                  const float* __restrict__ opacities, const float* __restrict__ sigmas,
                  const int32_t* __restrict__ visible, int64_t nv, ViewParams vp,
                  const TriRect* __restrict__ cull_rects, float* __restrict__ tris, TriRect* __restrict__ rects,
                  int32_t* __restrict__ visible_out) {
  __shared__ float sh_v[kThreads * 9];
  __shared__ float sh_t[kThreads * kTriStride];
  const int64_t base = (int64_t)blockIdx.x * kThreads;
  const int rows = (int)((nv - base) < kThreads ? (nv - base) : kThreads);
  load_rows<9, 9, kThreads>(vertices, visible, base, rows, sh_v);
  __syncthreads();
  if ((int)threadIdx.x < rows) {
    const int64_t k = base + threadIdx.x, i = visible[k];
    if (visible_out) visible_out[k] = (int32_t)i;
    PixelTri<float> t;
    TriRect r{0, 0, 0, 0};
    float key;
    preprocess_forward(sh_v + 9 * threadIdx.x, vp.cam, vp.k, vp.width, vp.height, t, r, key);
    t.color[0] = colors[3 * i], t.color[1] = colors[3 * i + 1], t.color[2] = colors[3 * i + 2];
    t.opacity = opacities[i];
    t.sigma = sigmas[i];
    t.index = (int32_t)i;
    const float* tf = reinterpret_cast<const float*>(&t);
#pragma unroll
    for (int c = 0; c < kTriFloats; ++c) sh_t[kTriStride * threadIdx.x + c] = tf[c];
    // The forward copies the cull pass's rectangle: the pair buffers were sized
    // from it, so the binning must see exactly that one.
    if (rects) rects[k] = cull_rects ? cull_rects[i] : r;
  }
  __syncthreads();
  store_rows<kTriFloats, kTriStride, kThreads>(sh_t, nullptr, base, rows, tris);
}

int blocks_for(int64_t n) { return (int)((n + kThreads - 1) / kThreads); }

}  // namespace

void launch_cull(const float* vertices, const float* opacities, int64_t n, const ViewParams& vp, TriRect* rects,
                 int32_t* tile_counts, float* keys, int64_t* total, cudaStream_t stream) {
  if (cudaMemsetAsync(total, 0, sizeof(int64_t), stream) != cudaSuccess || n == 0) return;  // error: the caller's check
  cull_kernel<<<blocks_for(n), kThreads, 0, stream>>>(vertices, opacities, n, vp, rects, tile_counts, keys,
                                                      reinterpret_cast<unsigned long long*>(total));
}

void launch_screen(const float* vertices, const float* colors, const float* opacities, const float* sigmas,
                   const int32_t* visible, int64_t nv, const ViewParams& vp, const TriRect* cull_rects,
                   PixelTri<float>* tris, TriRect* rects, int32_t* visible_out, cudaStream_t stream) {
  if (nv == 0) return;
  screen_kernel<<<blocks_for(nv), kThreads, 0, stream>>>(vertices, colors, opacities, sigmas, visible, nv, vp,
                                                         cull_rects, reinterpret_cast<float*>(tris), rects,
                                                         visible_out);
}

}  // namespace flat::render::cuda
