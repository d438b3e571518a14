// The tensor bundles between the autograd Function and the CPU / CUDA back
// ends of the Gaussian rasterizer (internal to src/gaussians): the splat
// rasterizers' shared ones (flat/render/shared/splat_buffers.h), scales (N,3).
#pragma once
#include "flat/render/shared/raster_dispatch.h"
#include "flat/render/shared/splat_buffers.h"
#include "gaussians/gaussian_math.h"

namespace flat::gaussians {

using GaussianInputs = render::SplatInputs;
using GaussianGrads = render::SplatGrads;
using GaussianOutputGrads = render::SplatOutputGrads;  // normal and distortion unused
using GaussianOutputs = render::RenderOutput;  // normal and distortion undefined

// The per-view images of `in`, uninitialised (every pixel gets written).
inline GaussianOutputs images_for(const GaussianInputs& in) {
  return render::empty_images(in.w2c.size(0), in.height, in.width, in.means.options(), /*normal=*/false,
                              /*distortion=*/false);
}

}  // namespace flat::gaussians
