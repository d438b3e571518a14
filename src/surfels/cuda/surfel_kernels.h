// Launchers of the surfel rasterizer's CUDA kernels. Plain header (no torch):
// the .cu files implement these; surfels/cuda/raster_surfels_cuda.cpp calls
// them, one chunk of views a call (ViewChunk, flat/render/shared/splat_tiles.h:
// element e = v * n + i is surfel i in view v), with buffers it allocates
// through libtorch. Everything is enqueued on `stream`, nothing synchronises.
#pragma once
#include <cstddef>
#include <cstdint>

#include <cuda_runtime.h>

#include "flat/render/shared/splat_tiles.h"
#include "surfels/surfel_math.h"

namespace flat::surfels::cuda {

// The splat kernels' 16 x 16 tiles (surfels cover tens of pixels each, unlike
// FLAT's ~2x2-pixel triangles: larger tiles, fewer pairs), per-view
// parameters (ViewParams) and tile_lo / tile_hi.
using namespace render::splat;

// Per element, each of the n surfels in each view of the chunk
// (surfels/cuda/preprocess.cu): tiles touched (0 when culled) and, for the
// others only, the PixelSurfel screen data (its `index`: the element),
// support box and depth sort key (render::depth_sort_key of the centre's
// camera z). The binning is the shared one (flat/render/shared/tile_lists.h:
// render::cuda::bin_rects) of these boxes.
void launch_preprocess(const float* means, const float* scales, const float* rotations, const float* colors,
                       const float* opacities, const ViewChunk& chunk, PixelSurfel<float>* surfels,
                       SurfelRect* rects, int32_t* tile_counts, uint32_t* depth_keys, cudaStream_t stream);

// Per-pixel state the forward keeps for the backward, (H,W) each: final
// transmittance, number of list entries processed, and the distortion's
// totals (the reference NDC depth m_ref and the sums of w m, w m^2, m from
// m_ref: the (3,H,W) `dist` map).
struct ForwardImages {  // the chunk's first view; each (C,H,W), the views one after another
  float* rgb;
  float* alpha;
  float* depth;
  float* normal;
  float* median;
  float* distortion;
  float* t_final;
  int32_t* last;
  float* dist;
};

// Compositing (surfels/cuda/raster_forward.cu): one block per tile of every
// view of the chunk. values: the sorted element indices; max_weight_bits (N):
// each surfel's largest blending weight so far (float bits, atomicMax).
void launch_raster_forward(const int2* ranges, const int32_t* values, const PixelSurfel<float>* surfels,
                           const ViewChunk& chunk, const ForwardImages& out, unsigned int* max_weight_bits,
                           cudaStream_t stream);

constexpr int kSurfelGradStride = 20;  // SurfelGrad's 18 floats, padded
static_assert(kSurfelGradStride >= kSurfelGradSize, "padded SurfelGrad rows");

struct BackwardImages {  // the chunk's first view (views one after another): upstream gradients and forward state
  const float* g_rgb;
  const float* g_alpha;
  const float* g_depth;
  const float* g_normal;
  const float* g_distortion;
  const float* t_final;
  const int32_t* last;
  const float* dist;
};

// Accumulates SurfelGrad<float> rows (kSurfelGradStride floats, by element)
// into surfel_grads (surfels/cuda/raster_backward.cu).
void launch_raster_backward(const int2* ranges, const int32_t* values, const PixelSurfel<float>* surfels,
                            const ViewChunk& chunk, const BackwardImages& in, float* surfel_grads,
                            cudaStream_t stream);

// Chain rule of one chunk (surfels/cuda/preprocess_backward.cu), one thread a
// surfel over the chunk's views: the rows of the elements visible
// (tile_counts > 0) to the inputs' gradients (added).
void launch_chain(const float* means, const float* scales, const float* rotations, const ViewChunk& chunk,
                  const int32_t* tile_counts, const float* surfel_grads, float* g_means, float* g_scales,
                  float* g_rotations, float* g_colors, float* g_opacities, cudaStream_t stream);

// Throws flat::Error naming `what` if the last launch failed (defined in the glue).
void check_launch(const char* what);

}  // namespace flat::surfels::cuda
