// CUDA back end of the surfel rasterizer (libtorch glue side). Views are
// rendered one after another; per view the forward keeps what the backward
// cannot cheaply recompute (the sorted (surfel, tile) list, the tile ranges,
// the per-pixel final transmittance, last entry and distortion totals):
// `views` holds those tensors. The surfels' screen data is recomputed.
#pragma once
#include <vector>

#include "surfels/surfel_buffers.h"

namespace flat::surfels::cuda {

// for_backward: keep the per-view state (else `views` stays empty).
SurfelOutputs forward(const SurfelInputs& in, bool for_backward, std::vector<at::Tensor>& views);
SurfelGrads backward(const SurfelInputs& in, const std::vector<at::Tensor>& views, const SurfelOutputGrads& grads);

}  // namespace flat::surfels::cuda
