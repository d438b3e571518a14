// One view's tile lists for primitives whose footprint is a pixel rectangle
// and a tile mask (3DGS and 2DGS): the shared binning of tile_binning.h run
// with buffers allocated through libtorch. CUDA builds only.
// Public, under flat/render/shared/, because gaussians and surfels call it.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>
#include <cuda_runtime.h>

#include "flat/render/shared/view_geometry.h"

namespace flat::render::cuda {

// Device arrays over the n primitives of one view, or of several views one
// after another (per_view elements a view), as a preprocessing pass leaves them.
struct RectFootprints {
  const uint32_t* depth_keys = nullptr;  // depth_sort_key() (any value where tile_counts is 0)
  const int32_t* tile_counts = nullptr;  // tiles its pairs go to; 0: none (culled)
  const PixelRect* rects = nullptr;      // pixel support (read where tile_counts > 0)
  const uint32_t* masks = nullptr;       // optional tile masks (launch_duplicate_rects); nullptr: every tile
  int64_t n = 0;
  int64_t per_view = 0;  // several views: the elements of each (n = views * per_view); 0: one view
};

struct TileLists {
  at::Tensor ids;     // (pairs) int: element indices, tile after tile, each tile's front to back
  at::Tensor ranges;  // (views * tiles, 2) int: tile t of view v's [start, end) in ids at row v * tiles + t
};

// Bins `views` views (fp.per_view elements each; one view: fp.per_view 0)
// of tiles_x * tiles_y tiles of tile_size pixels; pairs: the sum of the tile
// counts (the caller has it on the host). Tensors on the device of `opts`;
// enqueued on `stream`. `fn` names the rasterizer in errors.
TileLists bin_rects(const RectFootprints& fp, int64_t pairs, int tile_size, int tiles_x, int tiles_y, int views,
                    const at::TensorOptions& opts, cudaStream_t stream, const char* fn);

}  // namespace flat::render::cuda
