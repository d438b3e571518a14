// CPU reference Gaussian rasterizer: forward and analytic backward, in float
// or double (the dtype of the inputs). The oracle the CUDA kernels are tested
// against.
#pragma once
#include "gaussians/gaussian_buffers.h"

namespace flat::gaussians::cpu {

GaussianOutputs forward(const GaussianInputs& in);
// Recomputes the forward per view, then replays every pixel back to front.
GaussianGrads backward(const GaussianInputs& in, const GaussianOutputGrads& grads);

}  // namespace flat::gaussians::cpu
