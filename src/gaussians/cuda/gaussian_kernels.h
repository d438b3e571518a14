// Launchers of the Gaussian rasterizer's CUDA kernels. Plain header (no
// torch): the .cu files implement these; gaussians/cuda/raster_gaussians_cuda.cpp
// calls them with buffers it allocates through libtorch. One chunk of views
// a call (ViewChunk, flat/render/shared/splat_tiles.h: element e = v * n + i
// is Gaussian i in view v); everything is enqueued on `stream`, nothing
// synchronises.
#pragma once
#include <cuda_runtime.h>

#include <cstddef>
#include <cstdint>

#include "flat/render/shared/splat_tiles.h"
#include "gaussians/gaussian_math.h"

namespace flat::gaussians::cuda {

// The splat kernels' 16 x 16 tiles, per-view parameters (ViewParams) and
// tile_lo / tile_hi.
using namespace render::splat;

// Pass 1 over all n Gaussians in every view of the chunk, one element each
// (gaussians/cuda/preprocess.cu): screen data,
// pixel box, depth sort key (render::depth_sort_key; kCulledKey when culled),
// the mask of the box's tiles the support reaches (bit (ty - ty0) * tw +
// (tx - tx0); ~0u: every tile, for boxes of more than kMaskTiles tiles) and
// their count (0 when culled or no tile is reached: screen data, box and mask
// are then left unwritten); the sum of the tile counts (the chunk's pair
// count) into *total, zeroed first. The binning is the shared one
// (flat/render/shared/tile_lists.h: render::cuda::bin_rects) of these boxes
// and masks.
constexpr uint32_t kCulledKey = (1u << render::kDepthKeyBits) - 1u;  // sorts last
constexpr int kMaskTiles = 32;
void launch_preprocess(const float* means, const float* scales, const float* rotations, const float* colors,
                       const float* opacities, const ViewChunk& chunk, ScreenGaussian<float>* screen,
                       PixelBox* boxes, uint32_t* depth_keys, uint32_t* tile_masks, int32_t* tile_counts,
                       unsigned long long* total, cudaStream_t stream);

struct ForwardImages {  // the chunk's first view; each view channel-major (C,H,W), the views one after another
  float* rgb;
  float* alpha;
  float* depth;
  float* median;
  float* t_final;  // (views,H,W): final transmittance, kept for the backward
  int32_t* last;   // (views,H,W): list entries processed (of the pixel's tile), kept for the backward
};

// ranges: (views * tiles) rows; ids: element indices. max_weight_bits (N,
// zeroed once per call): each Gaussian's largest blending weight over the
// views so far (float bits, atomicMax).
void launch_raster_forward(const int2* ranges, const int32_t* ids, const ScreenGaussian<float>* screen,
                           const ViewChunk& chunk, const ForwardImages& out, unsigned int* max_weight_bits,
                           cudaStream_t stream);

// Rows of the per-view screen gradient buffer: ScreenGrad<float>'s fields,
// then zeros (whole 16-byte vectors, added with vector atomics).
constexpr int kGradStride = 12;
static_assert(kGradStride >= kScreenGradSize && kGradStride % 4 == 0, "padded ScreenGrad rows");

struct BackwardImages {  // the chunk's first view (views one after another): upstream gradients and the forward's per-pixel state
  const float* g_rgb;
  const float* g_alpha;
  const float* g_depth;
  const float* t_final;
  const int32_t* last;
};

// Accumulates ScreenGrad<float> rows (kGradStride floats, row = element index) into screen_grads.
void launch_raster_backward(const int2* ranges, const int32_t* ids, const ScreenGaussian<float>* screen,
                            const ViewChunk& chunk, const BackwardImages& in, float* screen_grads, cudaStream_t stream);

// The chain rule of one chunk (gaussians/cuda/preprocess.cu), one thread a
// Gaussian over the chunk's views: for every element with tile_counts > 0,
// its screen_grads row -> gradients of the inputs (added into the g_
// arrays); the row is zeroed for the next chunk.
void launch_chain(const float* means, const float* scales, const float* rotations, const ViewChunk& chunk,
                  const int32_t* tile_counts, float* screen_grads, float* g_means, float* g_scales, float* g_rotations,
                  float* g_colors, float* g_opacities, cudaStream_t stream);

// Throws flat::Error naming `what` if the last launch failed (defined in the glue).
void check_launch(const char* what);

}  // namespace flat::gaussians::cuda
