// Pixel-aligned Gaussians (paper, Table 1 baselines "FLAT 3DGS" / "FLAT 2DGS"):
// the same decoder, one primitive per token placed exactly as the ray-centred
// triangles (anchor ray, depth activation, ray frame: primitives/ray_anchors.h),
// so that only the primitive differs. The maths is in src/primitives/ray_gaussians.cpp.
//
//   mean      mu = o + D d
//   scales    s_k = f (shape_min + softplus(x_k + b)),  f = init_scale * D * per_pixel
//             (one standard deviation projects to init_scale pixels at x = 0)
//   rotation  q = q_F (x) normalize((1,0,0,0) + x_q): a quaternion in the ray
//             frame F = [e1 e2 d]; at x = 0 the axes are e1, e2, d, so a surfel
//             faces its camera (normal -d after the rasterizer's flip)
//   colour    cfg.colour_activation (sigmoid or tanh; no SH for Gaussians)
//   opacity   sigmoid(x - opacity_shift)
// The keys shared with the triangles come from TriangleParamConfig (depth_*,
// init_scale, shape_min, colour_activation, opacity_shift).
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"
#include "flat/primitives/gaussian_soup.h"
#include "flat/primitives/ray_triangles.h"

namespace flat::primitives {

// raw: (B,C,T,H/2,W/2) with C = gaussian_channels(scale_count).total; cams:
// B*T cameras frame-major; scale_count 3 (3DGS) or 2 (2DGS). fp32 output
// (fp64 for fp64 input), every op ATen (differentiable).
GaussianSoup build_gaussians(const at::Tensor& raw, const camera::Cameras& cams, int64_t image_height,
                             int64_t image_width, const TriangleParamConfig& cfg, int64_t scale_count);

}  // namespace flat::primitives
