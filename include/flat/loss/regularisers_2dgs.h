// The two geometric regularisers of 2DGS (Huang et al. 2024), used to train the
// 2DGS baseline (paper, Evaluation: "the original objective of normal
// self-consistency"), written against the rasterizer's outputs.
//
// Normal consistency:  L_n = mean_p (1 - n_p . (a_p N_p)),
//   n = rendered normal, a = detached alpha, N = normal of the surface implied
//   by the rendered depth (finite differences of back-projected points), both in
//   camera space facing the camera. Border pixels (no central difference) are
//   left out of the mean.
// Depth distortion:  L_d = mean_p sum_i sum_{j<i} w_i w_j (m_i - m_j)^2, with m
//   the depth mapped to NDC between near and far (2DGS: near 0.2, far 100). The
//   2DGS paper writes |m_i - m_j| over all pairs; its released rasterizer
//   accumulates the squared difference over ordered pairs, which we follow. The
//   per-pixel sum is accumulated by the rasterizer; here: the mean of that map,
//   and a reference that evaluates it from per-pixel sample lists.
#pragma once
#include <ATen/ATen.h>

namespace flat::loss {

// Camera-space normals (V,3,H,W) of the surface z = depth(u,v): points
// P = depth * ((u+0.5-cx)/fx, (v+0.5-cy)/fy, 1), N = normalize(dP/dv x dP/du)
// by central differences (faces the camera: (0,0,-1) for a fronto-parallel
// plane). depth: (V,1,H,W) z-depth; intrinsics: (V,4) normalised fx/W, fy/H,
// cx/W, cy/H. Border pixels are 0.
at::Tensor normals_from_depth(const at::Tensor& depth, const at::Tensor& intrinsics);

// normal: (V,3,H,W), depth, alpha: (V,1,H,W), intrinsics (V,4). Scalar.
at::Tensor normal_consistency_loss(const at::Tensor& normal, const at::Tensor& depth, const at::Tensor& alpha,
                                   const at::Tensor& intrinsics);

// Mean of the rasterizer's per-pixel distortion map (V,1,H,W). Scalar.
at::Tensor depth_distortion_loss(const at::Tensor& distortion);

// Reference per-pixel distortion: weights, depths (P,K) samples along each of
// P pixels (any order) -> (P) sum_i sum_{j<i} w_i w_j (m_i - m_j)^2,
// m = (far z - far near) / ((far - near) z) (2DGS' NDC map).
at::Tensor depth_distortion_reference(const at::Tensor& weights, const at::Tensor& depths, double near = 0.2,
                                      double far = 100.0);

}  // namespace flat::loss
