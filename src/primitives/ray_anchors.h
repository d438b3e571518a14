// What the pixel-aligned primitives share (internal to src/primitives): the
// anchor ray of each decoder token, the depth along it, the ray frame and
// footprint, and the activations. Used by ray_triangles.cpp (the paper's
// triangles) and ray_gaussians.cpp (the 3DGS / 2DGS baselines of Table 1), so
// all three representations place their primitives identically.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"
#include "flat/primitives/ray_triangles.h"

namespace flat::primitives {

// softplus(x + b) + lo with b such that the value at x = 0 is `at_zero`.
at::Tensor shifted_softplus(const at::Tensor& x, double lo, double at_zero);
// Depth along the anchor ray from the raw channel (cfg.depth_activation).
at::Tensor activate_depth(const at::Tensor& x, const TriangleParamConfig& cfg);
// RGB from raw channels (cfg.colour_activation; "sh" unflattens to (B,N,K,3)).
at::Tensor activate_colour(const at::Tensor& x, const TriangleParamConfig& cfg);
// (...,4) unit quaternion (w,x,y,z) -> (...,3,3) rotation matrix.
at::Tensor quaternion_to_matrix(const at::Tensor& q);
// (...,3,3) rotation matrix -> (...,4) unit quaternion (w >= 0).
at::Tensor matrix_to_quaternion(const at::Tensor& R);
// Hamilton product a b of (...,4) quaternions (w,x,y,z): the rotation b, then a.
at::Tensor quaternion_multiply(const at::Tensor& a, const at::Tensor& b);

// The anchor rays of a raw head output (B,C,T,H/2,W/2) and their frames.
struct RayAnchors {
  at::Tensor origins;     // (B,N,3) world
  at::Tensor directions;  // (B,N,3) world, unit
  at::Tensor frames;      // (B,N,3,3) world, columns e1 (~ image right), e2 (~ image down), d
  at::Tensor per_pixel;   // (B,N) world length per unit depth that projects to one full-resolution pixel
  at::Tensor tokens;      // (B,N,C) the raw channels, token order (t, i, j), fp32 (fp64 for fp64 input)
};

// Checks raw against `channels` (shape, floating point, even image size, half
// grid, B*T cameras frame-major; `what` names the caller in errors) and
// builds the anchors. Camera-dependent parts carry no gradient.
RayAnchors ray_anchors(const at::Tensor& raw, int64_t channels, const camera::Cameras& cams, int64_t image_height,
                       int64_t image_width, const std::string& what);

}  // namespace flat::primitives
