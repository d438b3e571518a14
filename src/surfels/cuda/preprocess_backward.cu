// Chain rule of the per-(view, surfel) preprocessing (surfels/cuda/preprocess.cu):
// the per-element screen gradients of one chunk of views (SurfelGrad rows
// summed by surfels/cuda/raster_backward.cu) to the means, scales, raw
// quaternions, colours and opacities. One thread per surfel, over the
// chunk's views in turn; chunks run one after another, so the adds need no
// atomics. The maths is preprocess_backward() of
// surfels/surfel_math.h, shared with the CPU reference.
#include "surfels/cuda/surfel_kernels.h"

namespace flat::surfels::cuda {
namespace {

constexpr int kThreads = 128;

__global__ void __launch_bounds__(kThreads)
    chain_kernel(const float* __restrict__ means, const float* __restrict__ scales,
                 const float* __restrict__ rotations, const __grid_constant__ ViewChunk chunk,
                 const int32_t* __restrict__ tile_counts, const float* __restrict__ surfel_grads,
                 float* __restrict__ g_means, float* __restrict__ g_scales, float* __restrict__ g_rotations,
                 float* __restrict__ g_colors, float* __restrict__ g_opacities) {
  const int64_t n = chunk.per_view;
  const int64_t i = (int64_t)blockIdx.x * kThreads + threadIdx.x;
  if (i >= n) return;
  float gc[3] = {0.f, 0.f, 0.f}, go = 0.f;
  float gm[3] = {0.f, 0.f, 0.f}, gs[2] = {0.f, 0.f}, gq[4] = {0.f, 0.f, 0.f, 0.f};
  bool any = false;
  for (int v = 0; v < chunk.views; ++v) {
    const int64_t e = v * n + i;
    if (tile_counts[e] == 0) continue;  // culled in this view: no row
    any = true;
    SurfelGrad<float> g;
    const float* row = surfel_grads + (int64_t)kSurfelGradStride * e;
    float* gp = reinterpret_cast<float*>(&g);
#pragma unroll
    for (int c = 0; c < kSurfelGradSize; ++c) gp[c] = row[c];
#pragma unroll
    for (int c = 0; c < 3; ++c) gc[c] += g.color[c];
    go += g.opacity;
    float vm[3] = {0.f, 0.f, 0.f}, vs[2] = {0.f, 0.f}, vq[4] = {0.f, 0.f, 0.f, 0.f};
    preprocess_backward(means + 3 * i, scales + 2 * i, rotations + 4 * i, chunk.v[v].cam, g, vm, vs, vq);
#pragma unroll
    for (int c = 0; c < 3; ++c) gm[c] += vm[c];
    gs[0] += vs[0], gs[1] += vs[1];
#pragma unroll
    for (int c = 0; c < 4; ++c) gq[c] += vq[c];
  }
  if (!any) return;
#pragma unroll
  for (int c = 0; c < 3; ++c) g_colors[3 * i + c] += gc[c];
  g_opacities[i] += go;
#pragma unroll
  for (int c = 0; c < 3; ++c) g_means[3 * i + c] += gm[c];
  g_scales[2 * i] += gs[0];
  g_scales[2 * i + 1] += gs[1];
#pragma unroll
  for (int c = 0; c < 4; ++c) g_rotations[4 * i + c] += gq[c];
}

}  // namespace

void launch_chain(const float* means, const float* scales, const float* rotations, const ViewChunk& chunk,
                  const int32_t* tile_counts, const float* surfel_grads, float* g_means, float* g_scales,
                  float* g_rotations, float* g_colors, float* g_opacities, cudaStream_t stream) {
  const int64_t n = chunk.per_view;
  if (n == 0) return;
  chain_kernel<<<(int)((n + kThreads - 1) / kThreads), kThreads, 0, stream>>>(
      means, scales, rotations, chunk, tile_counts, surfel_grads, g_means, g_scales, g_rotations, g_colors,
      g_opacities);
}

}  // namespace flat::surfels::cuda
