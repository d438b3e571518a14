// Differentiable 3D Gaussian splatting rasterizer (Kerbl et al. 2023): the
// "FLAT 3DGS" row of the paper's Table 1, the same scene decoder with heads
// that predict pixel-aligned 3D Gaussians instead of triangles. Built like the
// triangle rasterizer (src/render): a CPU reference and CUDA kernels with the
// same semantics, the maths in src/gaussians/gaussian_math.h shared by both;
// docs/rasterizer_3dgs.md has the equations and tolerances.
//
// Per Gaussian: Sigma = R S S^T R^T (R from the normalised quaternion, S =
// diag(scales)); EWA projection Sigma' = J W Sigma W^T J^T + 0.3 I (pixels^2,
// 3DGS' dilation), J evaluated at the mean with its screen position clamped to
// 1.3x the image's half-extent about the principal point (as 3DGS; gsplat's
// form for an off-centre principal point); conic = Sigma'^-1. Per pixel
// centre p (pixel (x,y) at (x+0.5, y+0.5)), d = p - mean2d, q = d^T conic d:
// alpha = min(alpha_max, opacity exp(-q/2)) inside the 3-sigma ellipse
// q <= 9, 0 outside (the support; its bounding box decides the tiles).
// Compositing, alpha_min / transmittance_min, background, alpha cap: exactly
// as the triangle rasterizer (front to back by camera depth of the mean, ties
// by index). A Gaussian whose mean is nearer than near_plane is culled.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"
#include "flat/render/rasterize.h"

namespace flat::gaussians {

// means (N,3) world; scales (N,3) > 0 (standard deviations, metres, along the
// rotated axes); rotations (N,4) quaternions (w,x,y,z), not necessarily unit
// (normalised inside; gradients flow to the raw values); colors (N,3);
// opacities (N) in [0,1]. Settings: render::CompositingSettings (a triangle
// RasterSettings passes as one; its window and culling fields are not read).
// Returns rgb, alpha, depth (sum_k w_k z_k, z_k = camera depth of mean k),
// median_depth, max_weight as render::rasterize; normal is undefined (3DGS has
// no surface normal: the paper takes 3DGS normals from depth finite
// differences, pipeline/scene_pipeline.cpp), distortion undefined.
// Differentiable w.r.t. means, scales, rotations, colors, opacities. CPU ->
// reference (double inputs run in double, for finite differences), CUDA ->
// kernels.
render::RenderOutput rasterize_gaussians(const at::Tensor& means, const at::Tensor& scales,
                                         const at::Tensor& rotations, const at::Tensor& colors,
                                         const at::Tensor& opacities, const camera::Cameras& cams, int64_t height,
                                         int64_t width, const render::CompositingSettings& settings);

}  // namespace flat::gaussians
