// Plain tensor bundles passed between the autograd Function and the CPU / CUDA
// back ends of the Gaussian rasterizer (internal to src/gaussians).
#pragma once
#include <ATen/ATen.h>

#include "gaussians/gaussian_math.h"

namespace flat::gaussians {

// Contiguous tensors on one device, one dtype (float; double on the CPU):
// means (N,3), scales (N,3), rotations (N,4), colors (N,3), opacities (N);
// on the host in that dtype: w2c (V,4,4), K (V,4) pixel intrinsics fx, fy,
// cx, cy, background (3).
struct GaussianInputs {
  at::Tensor means, scales, rotations, colors, opacities;
  at::Tensor w2c, K, background;
  int64_t height = 0, width = 0;
  CompositingConstants k;
  // The value checks' statistics (rasterize_gaussians.cpp), on the host; for
  // CUDA inputs filled by an asynchronous copy: read only once the stream
  // that computed them has been waited for. Empty when there are no Gaussians.
  at::Tensor value_stats;
};

// Fails unless the inputs are finite, opacities lie in [0, 1] and scales are
// positive, from in.value_stats (rasterize_gaussians.cpp).
void check_input_values(const GaussianInputs& in);

struct GaussianOutputs {
  at::Tensor rgb, alpha, depth, median_depth;  // (V,C,H,W)
  at::Tensor max_weight;                       // (N)

  // The per-view images of `in`, uninitialised (every pixel gets written).
  static GaussianOutputs images_for(const GaussianInputs& in) {
    const int64_t V = in.w2c.size(0), H = in.height, W = in.width;
    const auto f = in.means.options();
    GaussianOutputs out;
    out.rgb = at::empty({V, 3, H, W}, f);
    out.alpha = at::empty({V, 1, H, W}, f);
    out.depth = at::empty({V, 1, H, W}, f);
    out.median_depth = at::empty({V, 1, H, W}, f);
    return out;
  }
};

struct GaussianGrads {
  at::Tensor means, scales, rotations, colors, opacities;  // shapes of the inputs

  // Zeros: both back ends add each view's share into them.
  static GaussianGrads zeros_for(const GaussianInputs& in) {
    return {at::zeros_like(in.means), at::zeros_like(in.scales), at::zeros_like(in.rotations),
            at::zeros_like(in.colors), at::zeros_like(in.opacities)};
  }
};

}  // namespace flat::gaussians
