// Per-(view, surfel) preprocessing: one thread per surfel of all N; the maths
// is preprocess_forward() of surfels/surfel_math.h, shared with the CPU
// reference. The backward re-runs it (the same inputs give the same screen
// data, bit for bit) instead of keeping N records per view.
#include "surfels/cuda/surfel_kernels.h"

namespace flat::surfels::cuda {
namespace {

constexpr int kThreads = 128;

__global__ void __launch_bounds__(kThreads)
    preprocess_kernel(const float* __restrict__ means, const float* __restrict__ scales,
                      const float* __restrict__ rotations, const float* __restrict__ colors,
                      const float* __restrict__ opacities, int64_t n, ViewParams vp,
                      PixelSurfel<float>* __restrict__ surfels, SurfelRect* __restrict__ rects,
                      int32_t* __restrict__ tile_counts, uint32_t* __restrict__ depth_keys) {
  const int64_t i = (int64_t)blockIdx.x * kThreads + threadIdx.x;
  if (i >= n) return;
  PixelSurfel<float> s;
  SurfelRect r;
  float key = 0.f;
  int32_t count = 0;
  if (preprocess_forward(means + 3 * i, scales + 2 * i, rotations + 4 * i, opacities[i], vp.cam, vp.k, vp.width,
                         vp.height, s, r, key)) {
    count = tiles_touched(r);
    s.color[0] = colors[3 * i], s.color[1] = colors[3 * i + 1], s.color[2] = colors[3 * i + 2];
    s.opacity = opacities[i];
    s.index = (int32_t)i;
    surfels[i] = s;
    rects[i] = r;
    depth_keys[i] = render::depth_sort_key(key);
  }
  tile_counts[i] = count;
}

}  // namespace

void launch_preprocess(const float* means, const float* scales, const float* rotations, const float* colors,
                       const float* opacities, int64_t n, const ViewParams& vp, PixelSurfel<float>* surfels,
                       SurfelRect* rects, int32_t* tile_counts, uint32_t* depth_keys, cudaStream_t stream) {
  if (n == 0) return;
  preprocess_kernel<<<(int)((n + kThreads - 1) / kThreads), kThreads, 0, stream>>>(
      means, scales, rotations, colors, opacities, n, vp, surfels, rects, tile_counts, depth_keys);
}

}  // namespace flat::surfels::cuda
