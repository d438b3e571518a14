// The tensor bundles between the autograd Function and the CPU / CUDA back
// ends of the surfel rasterizer (internal to src/surfels): the splat
// rasterizers' shared ones (flat/render/shared/splat_buffers.h), scales
// (N,2); value_stats stays empty (rasterize_surfels checks the values first).
#pragma once
#include "flat/render/shared/raster_dispatch.h"
#include "flat/render/shared/splat_buffers.h"
#include "surfels/surfel_math.h"

namespace flat::surfels {

using SurfelInputs = render::SplatInputs;
using SurfelGrads = render::SplatGrads;
using SurfelOutputGrads = render::SplatOutputGrads;
using SurfelOutputs = render::RenderOutput;  // every field defined

// The per-view images of `in`, uninitialised (every pixel gets written).
inline SurfelOutputs images_for(const SurfelInputs& in) {
  return render::empty_images(in.w2c.size(0), in.height, in.width, in.means.options(), /*normal=*/true,
                              /*distortion=*/true);
}

}  // namespace flat::surfels
