// Chain rule of the per-(view, triangle) preprocessing
// (render/cuda/preprocess.cu): one view's per-triangle screen gradients
// (TriGrad, visible-list order, summed by render/cuda/raster_backward.cu) to
// the world vertices, colours, opacities and sigmas of the visible triangles.
// It zeroes the TriGrad rows it read, so that one buffer, zeroed once per
// backward, serves every view.
// The maths is preprocess_backward() of render/triangle_math.h, shared with
// the CPU reference. It runs ~50 divisions and 4 square roots per visible
// triangle and view: this file is compiled with -prec-div=false
// -prec-sqrt=false (2-ulp results, see CMakeLists.txt); the CUDA-vs-CPU
// gradient tolerances of docs/rasterizer.md hold with it.
#include "render/cuda/raster_kernels.h"
#include "render/cuda/row_staging.cuh"

namespace flat::render::cuda {
namespace {

constexpr int kThreads = 128;
constexpr int kGradStride = kTriGradStride + 1;  // odd: thread r reads its own row without bank conflicts

// 6 blocks per SM: at most 80 registers (12 bytes spilled); the compiler's 94
// allowed 5, and the kernel waits on its loads (H100, anchor-large step:
// 9.54 -> 9.24 ms; 7 blocks, 72 registers and 48 bytes spilled: 10.38 ms).
__global__ void __launch_bounds__(kThreads, 6)
    chain_kernel(const float* __restrict__ vertices, const int32_t* __restrict__ visible, int64_t nv,
                 float* __restrict__ tri_grads, ViewParams vp, float* __restrict__ g_vertices,
                 float* __restrict__ g_colors, float* __restrict__ g_opacities, float* __restrict__ g_sigmas) {
  __shared__ float sh_v[kThreads * 9];
  __shared__ float sh_g[kThreads * kGradStride];
  __shared__ float sh_c[kThreads * 3];
  const int64_t base = (int64_t)blockIdx.x * kThreads;
  const int rows = (int)((nv - base) < kThreads ? (nv - base) : kThreads);
  load_rows<9, 9, kThreads>(vertices, visible, base, rows, sh_v);
  load_rows<kTriGradStride, kGradStride, kThreads>(tri_grads, nullptr, base, rows, sh_g);
  __syncthreads();
  zero_rows<kTriGradStride, kThreads>(tri_grads, base, rows);  // ready for the next view
  if ((int)threadIdx.x < rows) {
    const int64_t k = base + threadIdx.x, i = visible[k];
    TriGrad<float> g;
    float* gp = reinterpret_cast<float*>(&g);
#pragma unroll
    for (int c = 0; c < kTriGradSize; ++c) gp[c] = sh_g[kGradStride * threadIdx.x + c];
    float gv[9];
#pragma unroll
    for (int c = 0; c < 9; ++c) gv[c] = 0.f;
    preprocess_backward(sh_v + 9 * threadIdx.x, vp.cam, g, gv);
#pragma unroll
    for (int c = 0; c < 9; ++c) sh_v[9 * threadIdx.x + c] = gv[c];  // own row: no other thread reads it now
    for (int c = 0; c < 3; ++c) sh_c[3 * threadIdx.x + c] = g.color[c];
    g_opacities[i] += g.opacity;
    g_sigmas[i] += g.sigma;
  }
  __syncthreads();
  add_rows<9, 9, kThreads>(sh_v, visible, base, rows, g_vertices);
  add_rows<3, 3, kThreads>(sh_c, visible, base, rows, g_colors);
}

int blocks_for(int64_t n) { return (int)((n + kThreads - 1) / kThreads); }

}  // namespace

void launch_chain(const float* vertices, const int32_t* visible, int64_t nv, float* tri_grads,
                  const ViewParams& vp, float* g_vertices, float* g_colors, float* g_opacities, float* g_sigmas,
                  cudaStream_t stream) {
  if (nv == 0) return;
  chain_kernel<<<blocks_for(nv), kThreads, 0, stream>>>(vertices, visible, nv, tri_grads, vp, g_vertices, g_colors,
                                                        g_opacities, g_sigmas);
}

}  // namespace flat::render::cuda
