#include "flat/data/frame_resize.h"

#include <cmath>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::data {

at::Tensor resize_images(const at::Tensor& images, int64_t height, int64_t width) {
  check_shape(images, {-1, -1, -1, -1}, "resize_images", "(K,C,H,W)");
  FLAT_CHECK(height > 0 && width > 0, "resize_images: target size must be positive");
  if (images.size(2) == height && images.size(3) == width) return images;
  const bool shrink = height < images.size(2) || width < images.size(3);
  if (shrink) return at::_upsample_bilinear2d_aa(images.contiguous(), {height, width}, false);
  return at::upsample_bilinear2d(images.contiguous(), {height, width}, false);
}

at::Tensor resize_depth(const at::Tensor& depth, int64_t height, int64_t width) {
  check_shape(depth, {-1, 1, -1, -1}, "resize_depth", "(K,1,H,W)");
  if (depth.size(2) == height && depth.size(3) == width) return depth;
  return at::_upsample_nearest_exact2d(depth.contiguous(), {height, width});
}

at::Tensor resize_normals(const at::Tensor& normals, int64_t height, int64_t width) {
  check_shape(normals, {-1, 3, -1, -1}, "resize_normals", "(K,3,H,W)");
  if (normals.size(2) == height && normals.size(3) == width) return normals;
  auto n = at::_upsample_nearest_exact2d(normals.contiguous(), {height, width});
  auto len = n.norm(2, 1, true);
  return at::where(len > 1e-6, n / len.clamp_min(1e-6), at::zeros_like(n));
}

Crop aspect_crop(int64_t H, int64_t W, int64_t h, int64_t w) {
  FLAT_CHECK(H > 0 && W > 0 && h > 0 && w > 0, "aspect_crop: sizes must be positive");
  Crop c{0, 0, H, W};
  // Compare W/H with w/h in integers to avoid rounding a matching ratio.
  if (W * h > w * H) {
    c.width = std::max<int64_t>(1, int64_t(std::llround(double(H) * double(w) / double(h))));
    c.left = (W - c.width) / 2;
  } else if (W * h < w * H) {
    c.height = std::max<int64_t>(1, int64_t(std::llround(double(W) * double(h) / double(w))));
    c.top = (H - c.height) / 2;
  }
  return c;
}

at::Tensor crop_intrinsics(const at::Tensor& intrinsics, int64_t H, int64_t W, const Crop& crop) {
  check_shape(intrinsics, {-1, 4}, "crop_intrinsics", "(K,4)");
  auto k = intrinsics.to(at::kDouble).clone();
  // Pixel units: focal lengths unchanged, principal point shifted by the crop origin.
  k.select(1, 0).mul_(double(W) / double(crop.width));
  k.select(1, 1).mul_(double(H) / double(crop.height));
  k.select(1, 2).mul_(double(W)).sub_(double(crop.left)).div_(double(crop.width));
  k.select(1, 3).mul_(double(H)).sub_(double(crop.top)).div_(double(crop.height));
  return k.to(intrinsics.scalar_type());
}

at::Tensor fit_frames(FrameBatch& f, const at::Tensor& intrinsics, int64_t height, int64_t width) {
  const int64_t H = f.images.size(2), W = f.images.size(3);
  Crop c = aspect_crop(H, W, height, width);
  auto cut = [&](const at::Tensor& t) {
    return t.defined() ? t.narrow(2, c.top, c.height).narrow(3, c.left, c.width) : t;
  };
  f.images = resize_images(cut(f.images), height, width);
  if (f.depth.defined()) f.depth = resize_depth(cut(f.depth), height, width);
  if (f.normals.defined()) f.normals = resize_normals(cut(f.normals), height, width);
  return crop_intrinsics(intrinsics, H, W, c);
}

}  // namespace flat::data
