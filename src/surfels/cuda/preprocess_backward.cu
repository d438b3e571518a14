// Chain rule of the per-(view, surfel) preprocessing (surfels/cuda/preprocess.cu):
// the per-surfel screen gradients of one view (SurfelGrad rows summed by
// surfels/cuda/raster_backward.cu) to the means, scales, raw quaternions,
// colours and opacities. One thread per surfel; views run one after another,
// so the adds need no atomics. The maths is preprocess_backward() of
// surfels/surfel_math.h, shared with the CPU reference.
#include "surfels/cuda/surfel_kernels.h"

namespace flat::surfels::cuda {
namespace {

constexpr int kThreads = 128;

__global__ void __launch_bounds__(kThreads)
    chain_kernel(const float* __restrict__ means, const float* __restrict__ scales,
                 const float* __restrict__ rotations, int64_t n, CameraView<float> cam,
                 const int32_t* __restrict__ tile_counts, const float* __restrict__ surfel_grads,
                 float* __restrict__ g_means, float* __restrict__ g_scales, float* __restrict__ g_rotations,
                 float* __restrict__ g_colors, float* __restrict__ g_opacities) {
  const int64_t i = (int64_t)blockIdx.x * kThreads + threadIdx.x;
  if (i >= n || tile_counts[i] == 0) return;  // culled in this view: no row
  SurfelGrad<float> g;
  const float* row = surfel_grads + (int64_t)kSurfelGradStride * i;
  float* gp = reinterpret_cast<float*>(&g);
#pragma unroll
  for (int c = 0; c < kSurfelGradSize; ++c) gp[c] = row[c];
#pragma unroll
  for (int c = 0; c < 3; ++c) g_colors[3 * i + c] += g.color[c];
  g_opacities[i] += g.opacity;
  float gm[3] = {0.f, 0.f, 0.f}, gs[2] = {0.f, 0.f}, gq[4] = {0.f, 0.f, 0.f, 0.f};
  preprocess_backward(means + 3 * i, scales + 2 * i, rotations + 4 * i, cam, g, gm, gs, gq);
#pragma unroll
  for (int c = 0; c < 3; ++c) g_means[3 * i + c] += gm[c];
  g_scales[2 * i] += gs[0];
  g_scales[2 * i + 1] += gs[1];
#pragma unroll
  for (int c = 0; c < 4; ++c) g_rotations[4 * i + c] += gq[c];
}

}  // namespace

void launch_chain(const float* means, const float* scales, const float* rotations, int64_t n,
                  const CameraView<float>& cam, const int32_t* tile_counts, const float* surfel_grads,
                  float* g_means, float* g_scales, float* g_rotations, float* g_colors, float* g_opacities,
                  cudaStream_t stream) {
  if (n == 0) return;
  chain_kernel<<<(int)((n + kThreads - 1) / kThreads), kThreads, 0, stream>>>(
      means, scales, rotations, n, cam, tile_counts, surfel_grads, g_means, g_scales, g_rotations, g_colors,
      g_opacities);
}

}  // namespace flat::surfels::cuda
