// CUDA back end of the Gaussian rasterizer (libtorch glue side). Views are
// rendered one after another; per view the forward keeps only what the
// backward cannot cheaply recompute (the sorted list ids, the tile ranges,
// per-pixel final transmittance and last entry): `views` holds those tensors.
// The screen data (ScreenGaussian) is recomputed by the backward, one cheap
// kernel a view.
#pragma once
#include <vector>

#include "gaussians/gaussian_buffers.h"

namespace flat::gaussians::cuda {

// for_backward: keep the per-view state (else `views` stays empty).
GaussianOutputs forward(const GaussianInputs& in, bool for_backward, std::vector<at::Tensor>& views);
GaussianGrads backward(const GaussianInputs& in, const std::vector<at::Tensor>& views,
                       const GaussianOutputGrads& grads);

}  // namespace flat::gaussians::cuda
