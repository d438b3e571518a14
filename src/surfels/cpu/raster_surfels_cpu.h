// CPU reference of the surfel rasterizer: forward and analytic backward, in
// float or double (the dtype of the inputs). The oracle the CUDA kernels are
// tested against.
#pragma once
#include "surfels/surfel_buffers.h"

namespace flat::surfels::cpu {

SurfelOutputs forward(const SurfelInputs& in);
// Recomputes the forward per view, then replays every pixel back to front.
SurfelGrads backward(const SurfelInputs& in, const SurfelOutputGrads& grads);

}  // namespace flat::surfels::cpu
