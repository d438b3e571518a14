// Per-(view, surfel) preprocessing: one thread an element (a surfel in a view
// of the chunk; grid y: the view); the maths
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
                      const float* __restrict__ opacities, const __grid_constant__ ViewChunk chunk,
                      PixelSurfel<float>* __restrict__ surfels, SurfelRect* __restrict__ rects,
                      int32_t* __restrict__ tile_counts, uint32_t* __restrict__ depth_keys) {
  const int64_t n = chunk.per_view;
  const int64_t i = (int64_t)blockIdx.x * kThreads + threadIdx.x;
  if (i >= n) return;
  const ViewParams& vp = chunk.v[blockIdx.y];
  const int64_t e = (int64_t)blockIdx.y * n + i;  // the element: surfel i in view blockIdx.y
  PixelSurfel<float> s;
  SurfelRect r;
  float key = 0.f;
  int32_t count = 0;
  if (preprocess_forward(means + 3 * i, scales + 2 * i, rotations + 4 * i, opacities[i], vp.cam, vp.k, vp.width,
                         vp.height, s, r, key)) {
    count = tiles_touched(r);
    s.color[0] = colors[3 * i], s.color[1] = colors[3 * i + 1], s.color[2] = colors[3 * i + 2];
    s.opacity = opacities[i];
    s.index = (int32_t)e;
    surfels[e] = s;
    rects[e] = r;
    depth_keys[e] = render::depth_sort_key(key);
  }
  tile_counts[e] = count;
}

}  // namespace

void launch_preprocess(const float* means, const float* scales, const float* rotations, const float* colors,
                       const float* opacities, const ViewChunk& chunk, PixelSurfel<float>* surfels,
                       SurfelRect* rects, int32_t* tile_counts, uint32_t* depth_keys, cudaStream_t stream) {
  const int64_t n = chunk.per_view;
  if (n == 0 || chunk.views == 0) return;
  const dim3 grid((unsigned)((n + kThreads - 1) / kThreads), (unsigned)chunk.views);
  preprocess_kernel<<<grid, kThreads, 0, stream>>>(means, scales, rotations, colors, opacities, chunk, surfels, rects,
                                                   tile_counts, depth_keys);
}

}  // namespace flat::surfels::cuda
