// Plain tensor bundles passed between the autograd Function and the CPU / CUDA
// back ends of the surfel rasterizer (internal to src/surfels).
#pragma once
#include <ATen/ATen.h>

#include "surfels/surfel_math.h"

namespace flat::surfels {

// All contiguous, one dtype (float; double on the CPU): means (N,3),
// scales (N,2), rotations (N,4), colors (N,3), opacities (N) on the inputs'
// device; w2c (V,4,4), K (V,4) pixel intrinsics fx, fy, cx, cy and
// background (3) on the host.
struct SurfelInputs {
  at::Tensor means, scales, rotations, colors, opacities;
  at::Tensor w2c, K, background;
  int64_t height = 0, width = 0;
  CompositingConstants k;
};

struct SurfelOutputs {
  at::Tensor rgb, alpha, depth, normal, median_depth, distortion;  // (V,C,H,W)
  at::Tensor max_weight;                                           // (N)

  // The per-view images of `in`, uninitialised (every pixel gets written).
  static SurfelOutputs images_for(const SurfelInputs& in) {
    const int64_t V = in.w2c.size(0), H = in.height, W = in.width;
    const auto f = in.means.options();
    SurfelOutputs out;
    out.rgb = at::empty({V, 3, H, W}, f);
    out.alpha = at::empty({V, 1, H, W}, f);
    out.depth = at::empty({V, 1, H, W}, f);
    out.normal = at::empty({V, 3, H, W}, f);
    out.median_depth = at::empty({V, 1, H, W}, f);
    out.distortion = at::empty({V, 1, H, W}, f);
    return out;
  }
};

// Upstream gradients, (V,C,H,W) each, defined (zeros where the output had none).
struct SurfelOutputGrads {
  at::Tensor rgb, alpha, depth, normal, distortion;
};

struct SurfelGrads {
  at::Tensor means, scales, rotations, colors, opacities;  // shapes of the inputs

  // Zeros: both back ends add each view's share into them.
  static SurfelGrads zeros_for(const SurfelInputs& in) {
    return {at::zeros_like(in.means), at::zeros_like(in.scales), at::zeros_like(in.rotations),
            at::zeros_like(in.colors), at::zeros_like(in.opacities)};
  }
};

}  // namespace flat::surfels
