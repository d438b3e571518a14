// Removing lens distortion without OpenCV: for each pixel of the undistorted
// output (same pinhole intrinsics), the forward OpenCV radial-tangential model
//   r2 = x^2 + y^2,  radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
//   xd = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
//   yd = y radial + p1 (r2 + 2 y^2) + 2 p2 x y
// gives the distorted source position, sampled bilinearly (at::grid_sample).
#pragma once
#include <ATen/ATen.h>

namespace flat::data {

struct Distortion {
  double k1 = 0, k2 = 0, k3 = 0, p1 = 0, p2 = 0;
  bool any() const { return k1 != 0 || k2 != 0 || k3 != 0 || p1 != 0 || p2 != 0; }
};

// Source pixel positions (H,W,2) (x, y in pixel units, centres at +0.5) of the
// distorted image for every pixel of the undistorted one.
at::Tensor distorted_positions(int64_t height, int64_t width, double fx, double fy, double cx, double cy,
                               const Distortion& d);

// (C,H,W) distorted image -> (C,H,W) undistorted image with the same pixel
// intrinsics fx, fy, cx, cy. Pixels whose source falls outside are 0.
at::Tensor undistort_image(const at::Tensor& image, double fx, double fy, double cx, double cy, const Distortion& d);

}  // namespace flat::data
