// Depth accuracy of rendered views against reference depth (issue #44:
// "texture leaks into geometry"), beside the normal L1 / cosine of
// normal_metrics.h. Both measures ignore a global scale of the depth, since a
// model's metric scale may differ from the reference's.
//
// Scale-invariant log error (Eigen et al. 2014), per view: with
//   d = log(rendered) - log(reference) over the view's valid pixels,
//   SI-log = sqrt(mean(d^2) - mean(d)^2)   (computed as the standard deviation
//   of d, two-pass, so a global scale gives 0 up to rounding).
// Valid: inside the mask (alpha > 0.5), both depths > 0.
//
// Planar roughness (texture leaking into depth): with z a depth map and
//   rho(z)(p) = z(p) * L(1/z)(p),  L(f)(p) = mean of f over p's 8 neighbours - f(p),
// rho is 0 on any plane (a pinhole camera sees a plane's inverse depth as an
// affine function of the pixel), unchanged by a global scale of z, and large
// where the depth carries texture (a checkerboard of relative amplitude e on
// a plane gives |rho| ~ e). A pixel is planar in the reference when its 3x3
// neighbourhood has reference depth, |rho(reference)| < kPlanarDepthTolerance,
// and (where reference normals exist) every neighbour's normal is within
// acos(kPlanarNormalCosine) of the centre's: this leaves out step edges and
// creases. Planar roughness = mean over the planar pixels whose 3x3
// neighbourhood is rendered (mask, depth > 0) of |rho(rendered) - rho(reference)|;
// a render whose depth equals the reference (or a multiple of it) scores 0.
#pragma once
#include <cmath>
#include <cstdint>
#include <vector>

#include <ATen/ATen.h>

namespace flat::eval {

// |rho(reference)| below this: planar (a step of 1% of the depth gives ~0.004).
inline constexpr double kPlanarDepthTolerance = 2e-3;
// Every neighbour's unit normal . the centre's at or above this (about 5.7 degrees).
inline constexpr double kPlanarNormalCosine = 0.995;

// (V,1,H,W) depth -> (V,1,H,W) float64 rho(z); NaN on the 1-pixel border and
// where any depth of the 3x3 neighbourhood is <= 0 (no depth).
at::Tensor relative_disparity_laplacian(const at::Tensor& depth);

// (V,1,H,W) reference depth, optional (V,3,H,W) reference normals (zero
// vectors: none) -> (V,1,H,W) bool: the reference's planar pixels.
at::Tensor planar_mask(const at::Tensor& reference, const at::Tensor& reference_normals = {});

// (V,1,H,W) rendered and reference depth, mask (V,1,H,W) bool (undefined = all)
// -> (V,) float64 SI-log error per view; NaN for a view without a valid pixel.
at::Tensor si_log_error(const at::Tensor& rendered, const at::Tensor& reference, const at::Tensor& mask = {});

struct DepthAccuracy {
  std::vector<double> si_log;        // per view; NaN where the view has no valid pixel
  double planar_roughness_sum = 0;   // sum of |rho(rendered) - rho(reference)| over the scored planar pixels
  int64_t planar_pixels = 0;         // planar pixels scored (all views)
  int64_t depth_pixels = 0;          // pixels scored by SI-log (all views)
  double planar_roughness() const {  // NaN without a scored planar pixel
    return planar_pixels > 0 ? planar_roughness_sum / double(planar_pixels) : NAN;
  }
};

// Both measures of the views; reference_normals may be undefined.
DepthAccuracy depth_accuracy(const at::Tensor& rendered, const at::Tensor& reference, const at::Tensor& mask,
                             const at::Tensor& reference_normals = {});

}  // namespace flat::eval
