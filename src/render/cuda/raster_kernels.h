// Launchers of the rasterizer's CUDA kernels. Plain header (no torch): the
// .cu files implement these; render/cuda/raster_cuda.cpp calls them with
// buffers it allocates through libtorch. One view per call; everything is
// enqueued on `stream`, nothing synchronises.
#pragma once
#include <cstddef>
#include <cstdint>

#include <cuda_runtime.h>

#include "render/triangle_math.h"

namespace flat::render::cuda {

// 8 x 8 pixels per tile, one thread per pixel. Smaller than the usual 16 x 16:
// FLAT scenes are dominated by ~2x2-pixel triangles, and a pixel evaluates
// every triangle of its tile, so small tiles evaluate ~3x fewer per pixel
// for a modestly longer sort.
constexpr int kTileSize = 8;
constexpr int kBlockSize = kTileSize * kTileSize;   // also the shared-memory batch size

struct ViewParams {
  CameraView<float> cam;
  RasterConstants k;
  int width = 0, height = 0;
  int tiles_x = 0, tiles_y = 0;
  float background[3] = {0.f, 0.f, 0.f};
};

// Tiles [x / kTileSize] touched by pixels [x0, x1) (x1 > x0).
FLAT_HD int tile_lo(int x0) { return x0 / kTileSize; }
FLAT_HD int tile_hi(int x1) { return (x1 - 1) / kTileSize + 1; }

// Per triangle: screen data (geometry + attributes), pixel support rectangle
// (TriRect, all zero when culled: the CPU reference shades exactly these
// pixels, and so do the kernels), number
// of tiles touched (int64, for the scan) and depth sort key.
void launch_preprocess(const float* vertices, const float* colors, const float* opacities, const float* sigmas,
                       int64_t n, const ViewParams& vp, PixelTri<float>* tris, TriRect* rects, int64_t* tile_counts,
                       float* keys, cudaStream_t stream);

// Inclusive prefix sum of tile_counts into offsets (cub); `temp` of temp_bytes
// (ask with temp == nullptr).
void scan_tile_counts(void* temp, size_t& temp_bytes, const int64_t* tile_counts, int64_t* offsets, int64_t n,
                      cudaStream_t stream);

// One (tile | depth) key and triangle id per touched tile.
void launch_duplicate(const TriRect* rects, const int64_t* offsets, const float* keys, int64_t n, int tiles_x,
                      uint64_t* pair_keys, int32_t* pair_ids, cudaStream_t stream);

// Stable radix sort of the pairs by key (cub), over the bits the keys use.
void sort_pairs(void* temp, size_t& temp_bytes, const uint64_t* keys_in, uint64_t* keys_out, const int32_t* ids_in,
                int32_t* ids_out, int64_t count, int num_tiles, cudaStream_t stream);

// ranges[t] = [start, end) of tile t in the sorted pairs (ranges zeroed first).
void launch_tile_ranges(const uint64_t* sorted_keys, int64_t count, int2* ranges, cudaStream_t stream);

struct ForwardImages {  // one view, channel-major (C,H,W)
  float* rgb;
  float* alpha;
  float* depth;
  float* normal;
  float* median;
  float* t_final;   // (H,W) final transmittance, kept for the backward
  int32_t* last;    // (H,W) number of list entries processed, kept for the backward
};

void launch_raster_forward(const int2* ranges, const int32_t* ids, const PixelTri<float>* tris, const TriRect* rects,
                           const ViewParams& vp,
                           const ForwardImages& out, unsigned int* max_weight_bits, cudaStream_t stream);

struct BackwardImages {  // one view: upstream gradients and the forward's per-pixel state
  const float* g_rgb;
  const float* g_alpha;
  const float* g_depth;
  const float* g_normal;
  const float* t_final;
  const int32_t* last;
};

// Accumulates TriGrad<float> (kTriGradSize floats per triangle) into tri_grads.
void launch_raster_backward(const int2* ranges, const int32_t* ids, const PixelTri<float>* tris,
                            const TriRect* rects, const ViewParams& vp, const BackwardImages& in, float* tri_grads, cudaStream_t stream);

// Chains one view's per-triangle gradients to the inputs (adds into the grads)
// and zeroes the tri_grads entries it read (those of the view's visible
// triangles, the only ones the backward rasterization writes), so the buffer
// is zeroed once per backward, not once per view.
void launch_preprocess_backward(const float* vertices, const TriRect* rects, float* tri_grads, int64_t n,
                                const ViewParams& vp, float* g_vertices, float* g_colors, float* g_opacities,
                                float* g_sigmas, cudaStream_t stream);

// Throws flat::Error naming `what` if the last launch failed (defined in the glue).
void check_launch(const char* what);

}  // namespace flat::render::cuda
