// CPU reference rasterizer: forward and analytic backward, in float or double
// (the dtype of the inputs). The oracle the CUDA kernels are tested against.
#pragma once
#include "render/raster_buffers.h"

namespace flat::render::cpu {

RasterOutputs forward(const RasterInputs& in);
// Recomputes the forward per view, then replays every pixel back to front.
RasterGrads backward(const RasterInputs& in, const at::Tensor& grad_rgb, const at::Tensor& grad_alpha,
                     const at::Tensor& grad_depth, const at::Tensor& grad_normal);

}  // namespace flat::render::cpu
