// Plain tensor bundles passed between the autograd Function and the CPU / CUDA
// back ends (internal to src/render).
#pragma once
#include <ATen/ATen.h>

#include "flat/render/shared/raster_dispatch.h"  // RenderOutput, empty_images
#include "flat/render/shared/triangle_math.h"

namespace flat::render {

// All contiguous tensors on one device, one dtype (float; double on the CPU):
// vertices (N,9), colors (N,3), opacities (N), sigmas (N), w2c (V,4,4),
// K (V,4) pixel intrinsics fx, fy, cx, cy; background (3).
struct RasterInputs {
  at::Tensor vertices, colors, opacities, sigmas;
  at::Tensor w2c, K, background;  // on the host, for either back end (rasterize.cpp)
  int64_t height = 0, width = 0;
  RasterConstants k;
  int64_t views_per_bin = 2;  // CUDA: views binned by one sort (RasterSettings::views_per_bin)
  // The value checks' statistics (rasterize.cpp), on the host; for CUDA
  // inputs filled by an asynchronous copy: read only once the stream that
  // computed them has been waited for. Empty when there are no triangles.
  at::Tensor value_stats;
};

// Fails unless the inputs are finite, opacities lie in [0, 1] and sigmas are
// positive, from in.value_stats (rasterize.cpp).
void check_input_values(const RasterInputs& in);

// rgb, alpha, depth, normal, median_depth (V,C,H,W) and max_weight (N).
using RasterOutputs = RenderOutput;

// The per-view images of `in`, uninitialised (every pixel gets written);
// max_weight is left to the back end.
inline RasterOutputs images_for(const RasterInputs& in) {
  return empty_images(in.w2c.size(0), in.height, in.width, in.vertices.options(), /*normal=*/true,
                      /*distortion=*/false);
}

struct RasterGrads {
  at::Tensor vertices, colors, opacities, sigmas;  // shapes of the inputs

  // Zeros: both back ends add each view's share into them.
  static RasterGrads zeros_for(const RasterInputs& in) {
    return {at::zeros_like(in.vertices), at::zeros_like(in.colors), at::zeros_like(in.opacities),
            at::zeros_like(in.sigmas)};
  }
};

}  // namespace flat::render
