// CUDA back end of the rasterizer (libtorch glue side). Views are processed
// in bin groups of two (RasterSettings::views_per_bin), one group after
// another; per view the forward keeps only what the backward cannot
// cheaply recompute (sorted ids, tile ranges, per-pixel final transmittance
// and last contributor, the list of visible triangles, and the visible
// triangles' screen data while it fits a memory budget): `views` holds those
// tensors.
#pragma once
#include <vector>

#include "flat/render/raster_load.h"
#include "render/raster_buffers.h"

namespace flat::render::cuda {

// for_backward: keep the per-view state (else `views` stays empty). load:
// when given, each view's load is counted into it (host syncs per view).
RasterOutputs forward(const RasterInputs& in, bool for_backward, std::vector<at::Tensor>& views,
                      std::vector<ViewLoad>* load = nullptr);
RasterGrads backward(const RasterInputs& in, const std::vector<at::Tensor>& views, const at::Tensor& grad_rgb,
                     const at::Tensor& grad_alpha, const at::Tensor& grad_depth, const at::Tensor& grad_normal);

}  // namespace flat::render::cuda
