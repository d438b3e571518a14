// Launchers of the rasterizer's CUDA kernels. Plain header (no torch): the
// .cu files implement these; render/cuda/raster_cuda.cpp calls them with
// buffers it allocates through libtorch. Culling and screen data: one view a
// call; binning and compositing: a bin group (up to kBinViews views); the
// chain rule: up to kChainViews views. Everything is enqueued on `stream`,
// nothing synchronises.
#pragma once
#include <cstddef>
#include <cstdint>

#include <cuda_runtime.h>

#include "flat/render/shared/tile_binning.h"
#include "flat/render/shared/triangle_math.h"

namespace flat::render::cuda {

// 8 x 8 pixels per tile, one thread per pixel. Smaller than the usual 16 x 16:
// FLAT scenes are dominated by ~2x2-pixel triangles, and a pixel evaluates
// every triangle of its tile, so small tiles evaluate ~3x fewer per pixel
// for a modestly longer sort.
constexpr int kTileSize = 8;
constexpr int kBlockSize = kTileSize * kTileSize;   // two warps, each on one 8x4 half (tile_pixel.cuh)

// The shared per-view fields (view_geometry.h), then the triangles' own
// (the same layout as the fields written out).
struct ViewParams : TileView<RasterConstants> {
  float inv_fx = 0.f, inv_fy = 0.f;  // 1 / cam.fx, 1 / cam.fy: pixel rays by multiplication
};
static_assert(sizeof(ViewParams) == sizeof(TileView<RasterConstants>) + 2 * sizeof(float), "ViewParams layout");

// A (triangle, tile) pair's id in the sorted lists: the triangle's
// visible-list index in bits 0-29, and in bit 30 + h whether its window
// support reaches a pixel centre of the tile's half h (rows 0-3, 4-7: the
// compositing warps' regions, render/cuda/tile_pixel.cuh). A support rectangle
// often meets a half that the triangle misses; the warp of that half then
// skips the entry without loading its rectangle or record. -1 marks no entry
// (so at most 2^30 - 1 visible triangles).
constexpr int kPairIndexBits = 30;
constexpr int64_t kMaxVisible = (int64_t(1) << kPairIndexBits) - 1;
FLAT_HD int pair_index(int32_t id) { return id & ((1 << kPairIndexBits) - 1); }
FLAT_HD bool pair_meets_half(int32_t id, int half) { return ((uint32_t)id >> (kPairIndexBits + half)) & 1u; }

// Tiles [x / kTileSize] touched by pixels [x0, x1) (x1 > x0).
FLAT_HD int tile_lo(int x0) { return x0 / kTileSize; }
FLAT_HD int tile_hi(int x1) { return (x1 - 1) / kTileSize + 1; }

// Pass 1 over all n triangles (render/cuda/preprocess.cu): tiles touched (0
// when culled) and, for the others only, the pixel support rectangle and the
// depth sort key; the sum of the tile counts (the view's pair count) into
// *total, zeroed first.
void launch_cull(const float* vertices, const float* opacities, int64_t n, const ViewParams& vp, TriRect* rects,
                 int32_t* tile_counts, float* keys, int64_t* total, cudaStream_t stream);

// Ascending ids of the triangles with tile_counts > 0 (cub select; count to
// *num_visible on the device); `temp` of temp_bytes (ask with temp == nullptr).
void select_visible(void* temp, size_t& temp_bytes, const int32_t* tile_counts, int64_t n, int32_t* visible,
                    int32_t* num_visible, cudaStream_t stream);

// Pass 2 over the nv visible triangles: screen data and support rectangle of
// visible[k] at index k (the CPU reference shades exactly these pixels, and so
// do the kernels). cull_rects: the cull pass's rectangles of all triangles,
// copied instead of recomputed (the forward: binning relies on them); nullptr
// recomputes them; rects == nullptr writes none (the backward, which reads
// the forward's coverage masks instead of rectangles). visible_out: when
// given, visible is copied there too (the forward's copy of the cull
// scratch's list into the bin group's, without a copy of its own).
void launch_screen(const float* vertices, const float* colors, const float* opacities, const float* sigmas,
                   const int32_t* visible, int64_t nv, const ViewParams& vp, const TriRect* cull_rects,
                   PixelTri<float>* tris, TriRect* rects, int32_t* visible_out, cudaStream_t stream);

// Binning of a bin group (render/cuda/binning.cu; the sorts, scan, tile
// ranges and tile order are the shared ones of tile_binning.h): up to
// kBinViews views binned by one depth sort and one tile sort, which pays the
// sorts' fixed host cost (a dozen calls each, whatever the size) once for the
// group. The group's visible list is its views' lists one after another
// (view j's from row first_j); pair ids index it, and tile ids count on
// through the views (view j's tile t is j * num_tiles + t), so the tile sort
// gives each view's lists apart. The depth sort may mix the views: each
// (view, tile) list still comes out front to back. In this order:
constexpr int kBinViews = 2;
// depth_bits[k] = the sort key of visible[k], order[k] = first + k (one
// view's rows of the group list, from row `first`);
void launch_depth_keys(const int32_t* visible, int64_t nv, const float* keys, int32_t first, uint32_t* depth_bits,
                       int32_t* order, cudaStream_t stream);
// sort_by_depth; then the tiles touched by each triangle in depth order, and
// their exclusive prefix sum (scan_counts);
void launch_ordered_counts(const int32_t* order, int64_t nv, const TriRect* rects, int32_t* counts,
                           cudaStream_t stream);
// one (tile id, pair id) pair per touched tile, in depth order (pair ids
// below: the visible-list index and the tile halves the window reaches);
// rows from `second` on are the group's second view's (its tile ids are
// offset by the view's tile count; second = nv for a group of one view);
void launch_duplicate(const int32_t* order, int64_t nv, const TriRect* rects, const PixelTri<float>* tris,
                      const ViewParams& vp, int32_t second, const int32_t* offsets, uint32_t* pair_tiles,
                      int32_t* pair_ids, cudaStream_t stream);
// then sort_by_tile (num_tiles: the group's), launch_tile_ranges and each
// view's launch_tile_order.

// Per list entry and tile half (the warps' 8x4 regions, tile_pixel.cuh): the
// region pixels where the entry's alpha reaches alpha_min (bit = pixel's lane),
// as the forward's coverage phase found them for the pixels still open at
// that round (0 for the others). Layout (2, pairs): half h of sorted entry i
// at bits[h * pairs + i]. Written for every entry of the rounds the forward
// ran, that is every entry before a pixel's last blended one; the backward
// reads them instead of re-testing coverage.
struct PairMasks {
  uint32_t* bits;  // nullptr: not written (a forward without backward)
  int64_t pairs;
};

// A compositing launch covers a bin group: block b composites tile
// tile_order[b] of view b / tiles (tiles = tiles_x * tiles_y of the
// ViewParams, whose other fields the views share). The views' ranges, tile
// orders and images lie one after another (ForwardImages, BackwardImages:
// the first view's; each image is (C,H,W) per view, the next view's C*H*W
// floats on); only their pixel rays differ (one launch, not one a view: one
// tail of short tiles a group, and half the launches).
struct GroupRays {
  int views = 1;
  float cx[kBinViews] = {}, cy[kBinViews] = {}, inv_fx[kBinViews] = {}, inv_fy[kBinViews] = {};
};

struct ForwardImages {  // the group's first view, channel-major (C,H,W)
  float* rgb;
  float* alpha;
  float* depth;
  float* normal;
  float* median;
  float* t_final;   // (H,W) a view: final transmittance, kept for the backward
  int32_t* last;    // (H,W) a view: number of list entries processed, kept for the backward
  PairMasks masks;  // kept for the backward
};

// ids index the bin group's visible list (tris, rects). max_weight_bits (N, zeroed once
// per call): each triangle's largest blending weight over the views so far
// (float bits, atomicMax at PixelTri::index).
void launch_raster_forward(const int2* ranges, const int32_t* tile_order, const int32_t* ids,
                           const PixelTri<float>* tris, const TriRect* rects, const ViewParams& vp,
                           const GroupRays& rays, const ForwardImages& out, unsigned int* max_weight_bits,
                           cudaStream_t stream);

constexpr int kTriGradStride = 20;  // five 16-byte vectors
static_assert(kTriGradStride >= kTriGradSize && kTriGradStride % 4 == 0, "padded TriGrad rows");

struct BackwardImages {  // the group's first view: upstream gradients and the forward's per-pixel state
  const float* g_rgb;
  const float* g_alpha;
  const float* g_depth;
  const float* g_normal;
  const float* t_final;
  const int32_t* last;
  PairMasks masks;  // the forward's
};

// Accumulates TriGrad<float> into tri_grads: one row of kTriGradStride floats
// per entry of the bin group's visible list (the kTriGradSize fields, then zeros: rows of whole
// 16-byte vectors, added with vector atomics).
void launch_raster_backward(const int2* ranges, const int32_t* tile_order, const int32_t* ids,
                            const PixelTri<float>* tris, const ViewParams& vp, const GroupRays& rays,
                            const BackwardImages& in, float* tri_grads, cudaStream_t stream);

// The chain rule of up to kChainViews views in one pass (preprocess_backward.cu).
// View v of the group: its camera and its row map (N entries: triangle i's
// row of tri_grads, -1 when culled). The views' rows lie one after another
// in tri_grads (a bin group's views are never split over two passes).
constexpr int kChainViews = 2;
static_assert(kBinViews <= kChainViews, "a bin group's views share one gradient buffer and one chain pass");
struct ChainViews {
  int count = 0;
  CameraView<float> cam[kChainViews];
  int32_t* row_of[kChainViews] = {};
  float* tri_grads = nullptr;
};

// row_of[visible[k]] = first_row + k for k < nv (row_of holds -1 elsewhere).
void launch_row_map(const int32_t* visible, int64_t nv, int32_t first_row, int32_t* row_of, cudaStream_t stream);

// Chains the group's per-triangle gradients to the inputs of the n triangles
// (adds into the grads), then zeroes the tri_grads rows and resets the row
// map entries it read (the buffers are set once per backward).
void launch_chain(const float* vertices, int64_t n, const ChainViews& cv, float* g_vertices, float* g_colors,
                  float* g_opacities, float* g_sigmas, cudaStream_t stream);

// Throws flat::Error naming `what` if the last launch failed (defined in the glue).
void check_launch(const char* what);

}  // namespace flat::render::cuda
