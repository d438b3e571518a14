#include "flat/loss/ssim.h"

#include <cmath>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::loss {

at::Tensor gaussian_window_1d(int64_t size, double sigma, const at::TensorOptions& options) {
  FLAT_CHECK(size > 0 && size % 2 == 1, "gaussian_window_1d: size must be odd, got " + std::to_string(size));
  FLAT_CHECK(sigma > 0, "gaussian_window_1d: sigma must be positive");
  // g_k = exp(-(k - c)^2 / (2 sigma^2)) / sum, computed in double.
  auto k = at::arange(size, at::kDouble) - double(size / 2);
  auto g = at::exp(-k.square() / (2 * sigma * sigma));
  return (g / g.sum()).to(options);
}

namespace {
// Separable 'valid' Gaussian filter of each channel of x (V,C,H,W).
at::Tensor filter(const at::Tensor& x, const at::Tensor& g) {
  const int64_t C = x.size(1), n = g.size(0);
  auto gx = g.view({1, 1, 1, n}).expand({C, 1, 1, n}).contiguous();
  auto gy = g.view({1, 1, n, 1}).expand({C, 1, n, 1}).contiguous();
  const std::vector<int64_t> one{1, 1}, zero{0, 0};
  auto y = at::conv2d(x, gx, at::Tensor(), one, zero, one, C);
  return at::conv2d(y, gy, at::Tensor(), one, zero, one, C);
}
}  // namespace

at::Tensor ssim_map(const at::Tensor& a, const at::Tensor& b, double data_range) {
  FLAT_CHECK(a.dim() == 4, "ssim: expected (V,C,H,W) images, got " + shape_str(a));
  FLAT_CHECK(a.sizes() == b.sizes(), "ssim: image shapes differ: " + shape_str(a) + " vs " + shape_str(b));
  FLAT_CHECK(a.size(2) >= 11 && a.size(3) >= 11, "ssim: images must be at least 11x11, got " + shape_str(a));
  auto x = a, y = b.to(a.dtype());
  auto g = gaussian_window_1d(11, 1.5, x.options());
  const double C1 = std::pow(0.01 * data_range, 2), C2 = std::pow(0.03 * data_range, 2);
  auto mx = filter(x, g), my = filter(y, g);
  auto sxx = filter(x * x, g) - mx * mx;
  auto syy = filter(y * y, g) - my * my;
  auto sxy = filter(x * y, g) - mx * my;
  return ((2 * mx * my + C1) * (2 * sxy + C2)) / ((mx * mx + my * my + C1) * (sxx + syy + C2));
}

at::Tensor ssim(const at::Tensor& a, const at::Tensor& b, double data_range) {
  return ssim_map(a, b, data_range).mean({1, 2, 3});
}

}  // namespace flat::loss
