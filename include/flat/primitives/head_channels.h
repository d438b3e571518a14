// The raw channel layout of the output heads: the ONE place that says which
// head output channel feeds which primitive parameter. The model's heads emit
// exactly this order; build_triangles() and build_gaussians() read exactly
// this order.
//
// Default ("ray_centred", RGB colour) = 12 channels per token:
//
//   ch  0       depth                 D = depth activation (positive)
//   ch  1.. 3   shape  L00, L10, L11  lower-triangular 2x2 transform (diag forced > 0)
//   ch  4.. 6   rotation tilt_x, tilt_y, spin   residual angles in the ray frame
//   ch  7.. 9   colour R, G, B
//   ch 10       opacity
//   ch 11       sigma (window sharpness)
//
// Ablation variants change only the group sizes, never the order:
//   "three_offsets":   shape = 6 channels (dx0, dy0, dx1, dy1, dx2, dy2): free 2-D
//                      offsets of the three vertices in the ray-tangent plane.
//   "global_rotation": rotation = 4 channels (qw, qx, qy, qz): a world-space
//                      quaternion (the identity is added before normalising).
// The 3DGS / 2DGS baselines (pipeline.representation "3dgs" / "2dgs"; paper,
// Table 1) keep the order and drop sigma:
//   ch 0 depth, ch 1.. scale (3 for 3DGS, 2 for 2DGS surfels), then rotation
//   (4: a quaternion in the ray frame), colour (3), opacity: 12 / 11 channels.
// Spherical harmonics (colour_activation "sh", degree k): colour = 3 (k+1)^2
// channels, coefficient-major: channel colour + 3*i + c holds coefficient i of
// colour channel c (i = 0 is the DC term).
#pragma once
#include <cstdint>
#include <string>

namespace flat::primitives {

struct HeadChannels {
  int64_t depth = 0;
  int64_t shape = 1, shape_count = 3;
  std::string shape_name = "cholesky";  // the head of the shape group: "cholesky" | "offsets" | "scale"

  int64_t rotation = 4, rotation_count = 3;
  int64_t colour = 7, colour_count = 3;
  int64_t opacity = 10;
  int64_t sigma = 11;  // -1: no sigma channel (the Gaussian layouts)
  int64_t total = 12;
};

// The default layout (ray_centred, RGB) has 12 channels.
inline constexpr int64_t kDefaultHeadChannels = 12;

// Number of SH coefficients per colour channel for a degree (0 -> 1, 3 -> 16).
inline int64_t sh_coefficient_count(int64_t sh_degree) { return (sh_degree + 1) * (sh_degree + 1); }

// Layout for a parameterisation ("ray_centred" | "three_offsets" |
// "global_rotation") and SH degree (0 = plain RGB). Throws flat::Error on an
// unknown parameterisation or a degree outside [0, 3].
HeadChannels triangle_channels(const std::string& parameterisation, int64_t sh_degree = 0);

// Layout of the Gaussian heads: scale_count 3 (3DGS) or 2 (2DGS surfels).
HeadChannels gaussian_channels(int64_t scale_count);

}  // namespace flat::primitives
