// The tile binning of the three CUDA rasterizers (triangles, 3DGS, 2DGS):
// from each primitive's depth key and the tiles its support touches to every
// tile's list of primitives, front to back. One algorithm
// (src/render/cuda/binning.cu): a stable radix sort of the primitives by
// depth (depth_sort_key(): 24 bits), then their (tile, primitive) pairs,
// written in that depth order, sorted stably by tile id alone (a short key),
// so each tile's list comes out front to back with equal depth keys in index
// order (the CPU references' stable sort). Sorting once by depth and then
// the pairs by a short key moves about half the bytes of one sort of the
// pairs by a 64-bit (tile | depth) key.
//
// What differs between primitives is only which tiles a primitive's pairs go
// to (its footprint): 3DGS and 2DGS give a pixel rectangle and, optionally, a
// mask of its tiles (launch_duplicate_rects); triangles add per pair the tile
// halves their window reaches (render/cuda/raster_kernels.h). Plain header
// (CUDA runtime, no torch): enqueued on `stream`, nothing synchronises;
// temporary storage sized with temp == nullptr.
// Public, under flat/render/shared/, because gaussians and surfels call it.
#pragma once
#include <cstddef>
#include <cstdint>

#include <cuda_runtime.h>

#include "flat/render/shared/view_geometry.h"

namespace flat::render::cuda {

// order[i] = i for i < n: the depth sort's values.
void launch_iota(int32_t* order, int64_t n, cudaStream_t stream);

// Stable radix sort of order by its depth keys (the kDepthKeyBits low bits).
void sort_by_depth(void* temp, size_t& temp_bytes, const uint32_t* depth_in, uint32_t* depth_out,
                   const int32_t* order_in, int32_t* order_out, int64_t n, cudaStream_t stream);

// Exclusive prefix sum of counts into offsets.
void scan_counts(void* temp, size_t& temp_bytes, const int32_t* counts, int32_t* offsets, int64_t n,
                 cudaStream_t stream);

// counts[r] = tile_counts[order[r]]: the tiles touched in depth order.
void launch_gather_counts(const int32_t* order, int64_t n, const int32_t* tile_counts, int32_t* counts,
                          cudaStream_t stream);

// One (tile id, primitive index) pair for each tile of order[r]'s rectangle
// (tiles of tile_size pixels, tiles_x a row) that its mask keeps (bit
// (ty - ty0) * tw + (tx - tx0) of the rectangle's tile range; masks ==
// nullptr or a mask of ~0u: every tile), written from offsets[r] on; counts
// (in depth order) must be the kept tiles' number. Several views binned at
// once: per_view > 0 primitives a view (element i belongs to view
// i / per_view), whose tile ids count on by tiles_per_view a view; 0: one view.
void launch_duplicate_rects(const int32_t* order, int64_t n, const int32_t* counts, const int32_t* offsets,
                            const PixelRect* rects, const uint32_t* masks, int tile_size, int tiles_x,
                            int64_t per_view, int tiles_per_view, uint32_t* pair_tiles, int32_t* pair_ids,
                            cudaStream_t stream);

// Stable radix sort of the pairs by tile id (num_tiles: the bits it needs):
// each tile's pairs stay front to back.
void sort_by_tile(void* temp, size_t& temp_bytes, const uint32_t* tiles_in, uint32_t* tiles_out,
                  const int32_t* ids_in, int32_t* ids_out, int64_t count, int num_tiles, cudaStream_t stream);

// ranges[t] = [start, end) of tile t in the sorted pairs (ranges zeroed first).
void launch_tile_ranges(const uint32_t* sorted_tiles, int64_t count, int2* ranges, cudaStream_t stream);

// Each view's compositing tile order (block b composites tile
// tile_order[b] of the view; views of num_tiles tiles one after another, in
// ranges and tile_order): longest lists first, so that the last wave of
// blocks holds the short ones (a counting sort into 256 length classes, one
// block a view).
void launch_tile_order(const int2* ranges, int num_tiles, int views, int32_t* tile_order, cudaStream_t stream);

}  // namespace flat::render::cuda
