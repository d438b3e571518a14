#include "flat/data/undistort.h"

#include "flat/core/shape.h"

namespace flat::data {

at::Tensor distorted_positions(int64_t H, int64_t W, double fx, double fy, double cx, double cy, const Distortion& d) {
  auto opt = at::TensorOptions().dtype(at::kDouble);
  auto v = at::arange(H, opt).view({H, 1}).expand({H, W}) + 0.5;
  auto u = at::arange(W, opt).view({1, W}).expand({H, W}) + 0.5;
  auto x = (u - cx) / fx, y = (v - cy) / fy;
  auto r2 = x * x + y * y;
  auto radial = 1 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3));
  auto xd = x * radial + 2 * d.p1 * x * y + d.p2 * (r2 + 2 * x * x);
  auto yd = y * radial + d.p1 * (r2 + 2 * y * y) + 2 * d.p2 * x * y;
  return at::stack({xd * fx + cx, yd * fy + cy}, -1);
}

at::Tensor undistort_image(const at::Tensor& image, double fx, double fy, double cx, double cy, const Distortion& d) {
  check_shape(image, {-1, -1, -1}, "undistort_image", "(C,H,W)");
  if (!d.any()) return image;
  const int64_t H = image.size(1), W = image.size(2);
  auto pos = distorted_positions(H, W, fx, fy, cx, cy, d);
  // grid_sample with align_corners=false: -1 and +1 are the outer edges of the image.
  auto gx = pos.select(-1, 0) * (2.0 / double(W)) - 1, gy = pos.select(-1, 1) * (2.0 / double(H)) - 1;
  auto grid = at::stack({gx, gy}, -1).unsqueeze(0).to(image.scalar_type());
  auto out = at::grid_sampler(image.unsqueeze(0), grid, /*bilinear*/ 0, /*zeros*/ 0, /*align_corners*/ false);
  return out[0];
}

}  // namespace flat::data
