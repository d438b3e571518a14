// CUDA back end of the rasterizer (libtorch glue side). Views are processed
// one after another; per view the forward keeps only what the backward cannot
// cheaply recompute (sorted ids, tile ranges, per-pixel final transmittance
// and last contributor, the list of visible triangles, and the visible
// triangles' screen data while it fits a memory budget): `views` holds those
// tensors.
#pragma once
#include <vector>

#include "render/raster_buffers.h"

namespace flat::render::cuda {

// for_backward: keep the per-view state (else `views` stays empty).
RasterOutputs forward(const RasterInputs& in, bool for_backward, std::vector<at::Tensor>& views);
RasterGrads backward(const RasterInputs& in, const std::vector<at::Tensor>& views, const at::Tensor& grad_rgb,
                     const at::Tensor& grad_alpha, const at::Tensor& grad_depth, const at::Tensor& grad_normal);

}  // namespace flat::render::cuda
