// Per-(view, Gaussian) kernels over a chunk of views (the maths is
// gaussians/gaussian_math.h, shared with the CPU reference):
//   preprocess  one thread an element (grid y: the view): screen data
//               (ScreenGaussian), pixel box, depth key and the tiles the
//               support reaches (tile_mask()), with the chunk's pair count
//               (one atomic a block);
//   chain       the backward's chain rule, one thread a Gaussian over the
//               chunk's views: its summed screen gradient of each view -> its
//               mean, scales, quaternion, colour and opacity (no atomics).
#include "flat/render/shared/block_sum.cuh"
#include "gaussians/cuda/gaussian_kernels.h"

namespace flat::gaussians::cuda {
namespace {

constexpr int kThreads = 128;

// Which tiles of the box b the support reaches: bit (ty - ty0) * tw + (tx - tx0)
// set when some pixel centre of the tile inside the box has q <= extent2
// (min_q_over_rect); every tile (all bits) when the box spans more than
// kMaskTiles tiles. Small Gaussians' boxes often straddle tile corners their
// ellipse misses: those pairs are never binned.
__device__ uint32_t tile_mask(const ScreenGaussian<float>& g, const PixelBox& b) {
  const int tx0 = tile_lo(b.x0), tx1 = tile_hi(b.x1), ty0 = tile_lo(b.y0), ty1 = tile_hi(b.y1);
  const int tw = tx1 - tx0;
  if (tw * (ty1 - ty0) > kMaskTiles) return ~0u;
  uint32_t mask = 0u;
  for (int ty = ty0; ty < ty1; ++ty)
    for (int tx = tx0; tx < tx1; ++tx) {
      const float x0 = (float)max(b.x0, tx * kTileSize) + 0.5f,
                  x1 = (float)(min(b.x1, (tx + 1) * kTileSize) - 1) + 0.5f;
      const float y0 = (float)max(b.y0, ty * kTileSize) + 0.5f,
                  y1 = (float)(min(b.y1, (ty + 1) * kTileSize) - 1) + 0.5f;
      if (min_q_over_rect(g, x0, x1, y0, y1) <= g.extent2) mask |= 1u << ((ty - ty0) * tw + (tx - tx0));
    }
  return mask;
}

__global__ void __launch_bounds__(kThreads)
    preprocess_kernel(const float* __restrict__ means, const float* __restrict__ scales,
                      const float* __restrict__ rotations, const float* __restrict__ colors,
                      const float* __restrict__ opacities, const __grid_constant__ ViewChunk chunk,
                      ScreenGaussian<float>* __restrict__ screen, PixelBox* __restrict__ boxes,
                      uint32_t* __restrict__ depth_keys, uint32_t* __restrict__ tile_masks,
                      int32_t* __restrict__ tile_counts, unsigned long long* __restrict__ total) {
  const int64_t n = chunk.per_view;
  const int64_t i = (int64_t)blockIdx.x * kThreads + threadIdx.x;
  const ViewParams& vp = chunk.v[blockIdx.y];
  const int64_t e = (int64_t)blockIdx.y * n + i;  // the element: Gaussian i in view blockIdx.y
  int32_t count = 0;
  if (i < n) {
    uint32_t key = kCulledKey;
    ScreenGaussian<float> g;
    PixelBox b;
    const float opacity = opacities[i];
    if (preprocess_forward(means + 3 * i, scales + 3 * i, rotations + 4 * i, opacity, vp.cam, vp.k, vp.width, vp.height,
                           g, b)) {
      g.opacity = opacity;
      for (int c = 0; c < 3; ++c) g.color[c] = colors[3 * i + c];
      g.pad = 0.f;
      const uint32_t mask = tile_mask(g, b);
      count = mask == ~0u ? tiles_touched(b) : __popc(mask);
      if (count > 0) {
        screen[e] = g;
        boxes[e] = b;
        tile_masks[e] = mask;
        key = render::depth_sort_key(g.z);
      }
    }
    depth_keys[e] = key;
    tile_counts[e] = count;
  }
  // The pair count, in 64 bits (it may pass 2^31: the host then fails clearly).
  render::cuda::add_block_sum<kThreads>(count, total);
}

__global__ void __launch_bounds__(kThreads)
    chain_kernel(const float* __restrict__ means, const float* __restrict__ scales, const float* __restrict__ rotations,
                 const __grid_constant__ ViewChunk chunk, const int32_t* __restrict__ tile_counts,
                 float* __restrict__ screen_grads, float* __restrict__ g_means, float* __restrict__ g_scales,
                 float* __restrict__ g_rotations, float* __restrict__ g_colors, float* __restrict__ g_opacities) {
  const int64_t n = chunk.per_view;
  const int64_t i = (int64_t)blockIdx.x * kThreads + threadIdx.x;
  if (i >= n) return;
  float gc[3] = {0.f, 0.f, 0.f}, go = 0.f;
  float gm[3] = {0.f, 0.f, 0.f}, gs[3] = {0.f, 0.f, 0.f}, gq[4] = {0.f, 0.f, 0.f, 0.f};
  bool any = false;
  for (int v = 0; v < chunk.views; ++v) {
    const int64_t e = v * n + i;
    if (tile_counts[e] == 0) continue;  // culled in this view: its row was never written
    any = true;
    float4* row = reinterpret_cast<float4*>(screen_grads + kGradStride * e);
    float r[kGradStride];
#pragma unroll
    for (int q = 0; q < kGradStride / 4; ++q) {
      const float4 a = row[q];
      r[4 * q] = a.x, r[4 * q + 1] = a.y, r[4 * q + 2] = a.z, r[4 * q + 3] = a.w;
      row[q] = make_float4(0.f, 0.f, 0.f, 0.f);  // ready for the next chunk
    }
    ScreenGrad<float> g;
    g.mean2d[0] = r[0], g.mean2d[1] = r[1];
    g.conic[0] = r[2], g.conic[1] = r[3], g.conic[2] = r[4];
    g.opacity = r[5];
    g.color[0] = r[6], g.color[1] = r[7], g.color[2] = r[8];
    g.z = r[9];
    for (int c = 0; c < 3; ++c) gc[c] += g.color[c];
    go += g.opacity;
    // Each view's share is summed in the order of the views (as the CPU reference).
    float vm[3] = {0.f, 0.f, 0.f}, vs[3] = {0.f, 0.f, 0.f}, vq[4] = {0.f, 0.f, 0.f, 0.f};
    const ViewParams& vp = chunk.v[v];
    preprocess_backward(means + 3 * i, scales + 3 * i, rotations + 4 * i, vp.cam, vp.width, vp.height, g, vm, vs, vq);
    for (int c = 0; c < 3; ++c) gm[c] += vm[c], gs[c] += vs[c];
    for (int c = 0; c < 4; ++c) gq[c] += vq[c];
  }
  if (!any) return;
  for (int c = 0; c < 3; ++c) g_colors[3 * i + c] += gc[c];
  g_opacities[i] += go;
  for (int c = 0; c < 3; ++c) g_means[3 * i + c] += gm[c], g_scales[3 * i + c] += gs[c];
  for (int c = 0; c < 4; ++c) g_rotations[4 * i + c] += gq[c];
}

int blocks_of(int64_t n) { return (int)((n + kThreads - 1) / kThreads); }

}  // namespace

void launch_preprocess(const float* means, const float* scales, const float* rotations, const float* colors,
                       const float* opacities, const ViewChunk& chunk, ScreenGaussian<float>* screen,
                       PixelBox* boxes, uint32_t* depth_keys, uint32_t* tile_masks, int32_t* tile_counts,
                       unsigned long long* total, cudaStream_t stream) {
  cudaMemsetAsync(total, 0, sizeof(unsigned long long), stream);
  if (chunk.per_view == 0 || chunk.views == 0) return;
  const dim3 grid(blocks_of(chunk.per_view), chunk.views);
  preprocess_kernel<<<grid, kThreads, 0, stream>>>(means, scales, rotations, colors, opacities, chunk, screen, boxes,
                                                   depth_keys, tile_masks, tile_counts, total);
}

void launch_chain(const float* means, const float* scales, const float* rotations, const ViewChunk& chunk,
                  const int32_t* tile_counts, float* screen_grads, float* g_means, float* g_scales, float* g_rotations,
                  float* g_colors, float* g_opacities, cudaStream_t stream) {
  if (chunk.per_view == 0) return;
  chain_kernel<<<blocks_of(chunk.per_view), kThreads, 0, stream>>>(means, scales, rotations, chunk, tile_counts,
                                                                   screen_grads, g_means, g_scales, g_rotations,
                                                                   g_colors, g_opacities);
}

}  // namespace flat::gaussians::cuda
