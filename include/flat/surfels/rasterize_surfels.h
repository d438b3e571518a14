// Differentiable 2D Gaussian surfel rasterizer (2DGS, Huang et al. 2024): the
// "FLAT 2DGS" row of the paper's Table 1, the same scene decoder with heads
// that predict pixel-aligned surfels. Built like the triangle rasterizer
// (src/render): a CPU reference and CUDA kernels with the same semantics, the
// maths in src/surfels/surfel_math.h shared by both.
//
// A surfel: centre p_k, tangent axes t_u, t_v (first two columns of R from the
// normalised quaternion), scales s_u, s_v; normal t_w = t_u x t_v. Each pixel
// is intersected with the surfel's plane (2DGS' ray-splat intersection through
// the homography of the plane; no affine approximation): local (u,v), rho3d =
// u^2 + v^2; 2DGS' object-space low-pass: rho = min(rho3d, 2 |p_px - c_px|^2)
// (c_px the projected centre; where the low-pass wins, depth is the centre's).
// alpha = min(alpha_max, opacity exp(-0.5 rho)); depth = camera z of the
// intersection point; normal = camera-space t_w, flipped to face the camera.
// Compositing, alpha_min / transmittance_min, background, alpha cap: exactly
// as the triangle rasterizer (front to back by camera depth of the centre,
// ties by index). A surfel whose centre is nearer than near_plane is culled;
// so is a fragment whose depth is (a ray meeting the plane behind the
// camera), and one beyond rho = 11.1 (3.33 sigma, where an opaque surfel's
// alpha passes below 1/255). docs/rasterizer_2dgs.md has the equations, the
// choices and the CUDA-vs-CPU tolerances.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"
#include "flat/render/rasterize.h"

namespace flat::surfels {

// 2DGS' depth distortion maps depth to NDC between these (its released code).
inline constexpr double kDistortionNear = 0.2;
inline constexpr double kDistortionFar = 100.0;

// means (N,3) world; scales (N,2) > 0 (standard deviations along t_u, t_v,
// metres); rotations (N,4) quaternions (w,x,y,z), not necessarily unit;
// colors (N,3); opacities (N) in [0,1]. Settings: render::CompositingSettings
// (a triangle RasterSettings passes as one; its window and culling fields
// are not read).
// Returns rgb, alpha, depth (alpha-weighted, not divided), normal
// (alpha-weighted, camera space, facing the camera), median_depth, max_weight
// as render::rasterize, and distortion (V,1,H,W): per pixel
// sum_i sum_{j<i} w_i w_j (m_i - m_j)^2, m = NDC depth between kDistortionNear
// and kDistortionFar (loss::depth_distortion_reference is its plain twin).
// Differentiable w.r.t. means, scales, rotations, colors, opacities through
// every output but median_depth and max_weight. CPU -> reference (double
// inputs run in double, for finite differences), CUDA -> kernels.
render::RenderOutput rasterize_surfels(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                                       const at::Tensor& colors, const at::Tensor& opacities,
                                       const camera::Cameras& cams, int64_t height, int64_t width,
                                       const render::CompositingSettings& settings);

}  // namespace flat::surfels
