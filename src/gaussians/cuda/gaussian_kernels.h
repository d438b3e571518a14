// Launchers of the Gaussian rasterizer's CUDA kernels. Plain header (no
// torch): the .cu files implement these; gaussians/cuda/raster_gaussians_cuda.cpp
// calls them with buffers it allocates through libtorch. One view a call;
// everything is enqueued on `stream`, nothing synchronises.
#pragma once
#include <cstddef>
#include <cstdint>

#include <cuda_runtime.h>

#include "gaussians/gaussian_math.h"

namespace flat::gaussians::cuda {

// 16 x 16 pixels per tile, one thread per pixel (3DGS' tiles).
constexpr int kTileSize = 16;
constexpr int kBlockSize = kTileSize * kTileSize;

struct ViewParams {
  CameraView<float> cam;
  GaussianConstants k;
  int width = 0, height = 0;
  int tiles_x = 0, tiles_y = 0;
  float background[3] = {0.f, 0.f, 0.f};
};

// Tiles [x / kTileSize] touched by pixels [x0, x1) (x1 > x0).
FLAT_HD int tile_lo(int x0) { return x0 / kTileSize; }
FLAT_HD int tile_hi(int x1) { return (x1 - 1) / kTileSize + 1; }

// Pass 1 over all n Gaussians (gaussians/cuda/preprocess.cu): screen data,
// pixel box, depth sort key (render::depth_sort_key) and tiles touched
// (0 when culled; the other arrays are then left unwritten); the sum of the
// tile counts (the view's pair count) into *total, zeroed first.
void launch_preprocess(const float* means, const float* scales, const float* rotations, const float* colors,
                       const float* opacities, int64_t n, const ViewParams& vp, ScreenGaussian<float>* screen,
                       PixelBox* boxes, uint32_t* depth_keys, int32_t* tile_counts, unsigned long long* total,
                       cudaStream_t stream);

// Binning (gaussians/cuda/binning.cu), in this order:
// inclusive prefix sum of the tile counts (cub; temp sized with temp == nullptr);
void scan_tile_counts(void* temp, size_t& temp_bytes, const int32_t* counts, int32_t* ends, int64_t n,
                      cudaStream_t stream);
// one pair per touched tile: key (tile << 24 | depth key), value the Gaussian's index;
void launch_duplicate(const int32_t* counts, const int32_t* ends, const PixelBox* boxes, const uint32_t* depth_keys,
                      int64_t n, const ViewParams& vp, uint64_t* keys, int32_t* ids, cudaStream_t stream);
// stable radix sort of the pairs by key (num_tiles: the bits it needs): each
// tile's list front to back, ties by index;
void sort_pairs(void* temp, size_t& temp_bytes, const uint64_t* keys_in, uint64_t* keys_out, const int32_t* ids_in,
                int32_t* ids_out, int64_t count, int num_tiles, cudaStream_t stream);
// ranges[t] = [start, end) of tile t in the sorted pairs (ranges zeroed first).
void launch_tile_ranges(const uint64_t* sorted_keys, int64_t count, int2* ranges, cudaStream_t stream);

struct ForwardImages {  // one view, channel-major (C,H,W)
  float* rgb;
  float* alpha;
  float* depth;
  float* median;
  float* t_final;  // (H,W): final transmittance, kept for the backward
  int32_t* last;   // (H,W): list entries processed (of the pixel's tile), kept for the backward
};

// max_weight_bits (N, zeroed once per call): each Gaussian's largest blending
// weight over the views so far (float bits, atomicMax).
void launch_raster_forward(const int2* ranges, const int32_t* ids, const ScreenGaussian<float>* screen,
                           const ViewParams& vp, const ForwardImages& out, unsigned int* max_weight_bits,
                           cudaStream_t stream);

// Rows of the per-view screen gradient buffer: ScreenGrad<float>'s fields,
// then zeros (whole 16-byte vectors, added with vector atomics).
constexpr int kGradStride = 12;
static_assert(kGradStride >= kScreenGradSize && kGradStride % 4 == 0, "padded ScreenGrad rows");

struct BackwardImages {  // one view: upstream gradients and the forward's per-pixel state
  const float* g_rgb;
  const float* g_alpha;
  const float* g_depth;
  const float* t_final;
  const int32_t* last;
};

// Accumulates ScreenGrad<float> rows (kGradStride floats, row = Gaussian index) into screen_grads.
void launch_raster_backward(const int2* ranges, const int32_t* ids, const ScreenGaussian<float>* screen,
                            const ViewParams& vp, const BackwardImages& in, float* screen_grads, cudaStream_t stream);

// The chain rule of one view (gaussians/cuda/preprocess.cu): for every
// Gaussian with tile_counts > 0, its screen_grads row -> gradients of the
// inputs (added into the g_ arrays); the row is zeroed for the next view.
void launch_chain(const float* means, const float* scales, const float* rotations, int64_t n, const ViewParams& vp,
                  const int32_t* tile_counts, float* screen_grads, float* g_means, float* g_scales,
                  float* g_rotations, float* g_colors, float* g_opacities, cudaStream_t stream);

// Throws flat::Error naming `what` if the last launch failed (defined in the glue).
void check_launch(const char* what);

}  // namespace flat::gaussians::cuda
