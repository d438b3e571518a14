// Chain rule of the per-(view, triangle) preprocessing
// (render/cuda/preprocess.cu): the per-triangle screen gradients (TriGrad,
// visible-list order, summed by render/cuda/raster_backward.cu) of up to
// kChainViews views at once, to the world vertices, colours, opacities and
// sigmas. One thread per triangle: it adds the views' gradients in registers
// and reads and writes its input rows and gradient rows once for the group,
// not once per view. The pass is bound by memory (~300 bytes per visible
// triangle and view one view at a time, half of it the gradients'
// read-modify-write), so two views a launch cut its traffic by ~40%.
// It zeroes the TriGrad rows it read and resets the row maps it read to -1,
// so that the buffers, set once per backward, serve every group.
// The maths is preprocess_backward() of flat/render/shared/triangle_math.h, shared with
// the CPU reference. It runs ~50 divisions and 4 square roots per visible
// triangle and view: this file is compiled with -prec-div=false
// -prec-sqrt=false (2-ulp results, see CMakeLists.txt); the CUDA-vs-CPU
// gradient tolerances of docs/rasterizer.md hold with it.
#include "render/cuda/raster_kernels.h"
#include "render/cuda/row_staging.cuh"

namespace flat::render::cuda {
namespace {

constexpr int kThreads = 128;

// 5 blocks per SM: 96 registers, no spills (at 6 blocks: 80 registers with
// spills, anchor-large's chain 6.85 against 6.59 ms a step on the H100).
__global__ void __launch_bounds__(kThreads, 5)
    chain_kernel(const float* __restrict__ vertices, int64_t n, ChainViews cv, float* __restrict__ g_vertices,
                 float* __restrict__ g_colors, float* __restrict__ g_opacities, float* __restrict__ g_sigmas) {
  __shared__ float sh_v[kThreads * 9];
  __shared__ float sh_c[kThreads * 3];
  const int64_t base = (int64_t)blockIdx.x * kThreads, i = base + threadIdx.x;
  const int rows = (int)((n - base) < kThreads ? (n - base) : kThreads);
  int32_t k[kChainViews];
  bool seen = false;  // visible in a view of the group
#pragma unroll
  for (int v = 0; v < kChainViews; ++v) {
    k[v] = v < cv.count && i < n ? cv.row_of[v][i] : -1;
    seen |= k[v] >= 0;
  }
  if (!__syncthreads_or(seen)) return;  // no triangle of the block is visible in these views
  load_rows<9, 9, kThreads>(vertices, nullptr, base, rows, sh_v);
  __syncthreads();
  float gv[9], gc[3] = {0.f, 0.f, 0.f}, g_opacity = 0.f, g_sigma = 0.f;
#pragma unroll
  for (int c = 0; c < 9; ++c) gv[c] = 0.f;
#pragma unroll
  for (int v = 0; v < kChainViews; ++v) {
    if (k[v] < 0) continue;
    cv.row_of[v][i] = -1;  // ready for the next group
    float4* row = reinterpret_cast<float4*>(cv.tri_grads + (int64_t)kTriGradStride * k[v]);
    float4 r[kTriGradStride / 4];
#pragma unroll
    for (int q = 0; q < kTriGradStride / 4; ++q) r[q] = row[q];
#pragma unroll
    for (int q = 0; q < kTriGradStride / 4; ++q) row[q] = make_float4(0.f, 0.f, 0.f, 0.f);  // ready for the next group
    TriGrad<float> g;
    const float* rf = reinterpret_cast<const float*>(r);
    float* gp = reinterpret_cast<float*>(&g);
#pragma unroll
    for (int c = 0; c < kTriGradSize; ++c) gp[c] = rf[c];
    preprocess_backward(sh_v + 9 * threadIdx.x, cv.cam[v], g, gv);
#pragma unroll
    for (int c = 0; c < 3; ++c) gc[c] += g.color[c];
    g_opacity += g.opacity;
    g_sigma += g.sigma;
  }
  __syncthreads();  // every thread's vertices read before the rows are reused for the gradients
#pragma unroll
  for (int c = 0; c < 9; ++c) sh_v[9 * threadIdx.x + c] = gv[c];
#pragma unroll
  for (int c = 0; c < 3; ++c) sh_c[3 * threadIdx.x + c] = gc[c];
  if (seen) {
    g_opacities[i] += g_opacity;
    g_sigmas[i] += g_sigma;
  }
  __syncthreads();
  // Whole rows of the block (zeros added for the triangles no view saw): coalesced.
  add_rows<9, 9, kThreads>(sh_v, nullptr, base, rows, g_vertices);
  add_rows<3, 3, kThreads>(sh_c, nullptr, base, rows, g_colors);
}

__global__ void row_map_kernel(const int32_t* __restrict__ visible, int64_t nv, int32_t first_row,
                               int32_t* __restrict__ row_of) {
  const int64_t k = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (k < nv) row_of[visible[k]] = first_row + (int32_t)k;
}

int blocks_for(int64_t n, int threads) { return (int)((n + threads - 1) / threads); }

}  // namespace

void launch_row_map(const int32_t* visible, int64_t nv, int32_t first_row, int32_t* row_of, cudaStream_t stream) {
  if (nv == 0) return;
  row_map_kernel<<<blocks_for(nv, 256), 256, 0, stream>>>(visible, nv, first_row, row_of);
}

void launch_chain(const float* vertices, int64_t n, const ChainViews& cv, float* g_vertices, float* g_colors,
                  float* g_opacities, float* g_sigmas, cudaStream_t stream) {
  if (n == 0 || cv.count == 0) return;
  chain_kernel<<<blocks_for(n, kThreads), kThreads, 0, stream>>>(vertices, n, cv, g_vertices, g_colors, g_opacities,
                                                                 g_sigmas);
}

}  // namespace flat::render::cuda
