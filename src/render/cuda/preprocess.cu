// Per-(view, triangle) preprocessing: projection, window geometry, depth
// plane, tile rectangle and sort key (forward); and its chain rule from the
// per-triangle screen gradients to the world vertices (backward). The maths
// is render/triangle_math.h, shared with the CPU reference.
#include "render/cuda/raster_kernels.h"

namespace flat::render::cuda {
namespace {

__global__ void preprocess_kernel(const float* __restrict__ vertices, const float* __restrict__ colors,
                                  const float* __restrict__ opacities, const float* __restrict__ sigmas, int64_t n,
                                  ViewParams vp, PixelTri<float>* __restrict__ tris, TriRect* __restrict__ rects,
                                  int64_t* __restrict__ tile_counts, float* __restrict__ keys) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  TriRect tr{0, 0, 0, 0};  // pixel support rectangle, empty when culled
  int64_t count = 0;
  const float op = opacities[i];
  PixelTri<float> t;
  TriRect r;
  float key = 0.f;
  const bool can_show = !(vp.k.alpha_min > 0.f) || op >= vp.k.alpha_min;
  float v[9];
#pragma unroll
  for (int c = 0; c < 9; ++c) v[c] = vertices[9 * i + c];
  if (can_show && preprocess_forward(v, vp.cam, vp.k, vp.width, vp.height, t, r, key)) {
    t.color[0] = colors[3 * i], t.color[1] = colors[3 * i + 1], t.color[2] = colors[3 * i + 2];
    t.opacity = op;
    t.sigma = sigmas[i];
    tris[i] = t;
    tr = r;
    count = (int64_t)(tile_hi(r.x1) - tile_lo(r.x0)) * (tile_hi(r.y1) - tile_lo(r.y0));
  }
  rects[i] = tr;
  tile_counts[i] = count;
  keys[i] = key;
}

__global__ void preprocess_backward_kernel(const float* __restrict__ vertices, const TriRect* __restrict__ rects,
                                           float* __restrict__ tri_grads, int64_t n, ViewParams vp,
                                           float* __restrict__ g_vertices, float* __restrict__ g_colors,
                                           float* __restrict__ g_opacities, float* __restrict__ g_sigmas) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  const TriRect tr = rects[i];
  if (tr.x0 >= tr.x1 || tr.y0 >= tr.y1) return;  // culled in this view
  TriGrad<float> g;
  float* gp = reinterpret_cast<float*>(&g);
#pragma unroll
  for (int c = 0; c < kTriGradSize; ++c) {
    gp[c] = tri_grads[kTriGradSize * i + c];
    tri_grads[kTriGradSize * i + c] = 0.f;  // ready for the next view: only visible triangles were written
  }
  float v[9], gv[9];
#pragma unroll
  for (int c = 0; c < 9; ++c) v[c] = vertices[9 * i + c], gv[c] = 0.f;
  preprocess_backward(v, vp.cam, g, gv);
#pragma unroll
  for (int c = 0; c < 9; ++c) g_vertices[9 * i + c] += gv[c];
  for (int c = 0; c < 3; ++c) g_colors[3 * i + c] += g.color[c];
  g_opacities[i] += g.opacity;
  g_sigmas[i] += g.sigma;
}

int blocks_for(int64_t n, int threads) { return (int)((n + threads - 1) / threads); }

}  // namespace

void launch_preprocess(const float* vertices, const float* colors, const float* opacities, const float* sigmas,
                       int64_t n, const ViewParams& vp, PixelTri<float>* tris, TriRect* rects, int64_t* tile_counts,
                       float* keys, cudaStream_t stream) {
  if (n == 0) return;
  preprocess_kernel<<<blocks_for(n, 256), 256, 0, stream>>>(vertices, colors, opacities, sigmas, n, vp, tris, rects,
                                                            tile_counts, keys);
}

void launch_preprocess_backward(const float* vertices, const TriRect* rects, float* tri_grads, int64_t n,
                                const ViewParams& vp, float* g_vertices, float* g_colors, float* g_opacities,
                                float* g_sigmas, cudaStream_t stream) {
  if (n == 0) return;
  preprocess_backward_kernel<<<blocks_for(n, 256), 256, 0, stream>>>(vertices, rects, tri_grads, n, vp, g_vertices,
                                                                     g_colors, g_opacities, g_sigmas);
}

}  // namespace flat::render::cuda
