#include "flat/camera/rays.h"

#include "flat/core/small_matmul.h"
#include "flat/core/error.h"

namespace flat::camera {

Rays pixel_rays(const Cameras& cameras, int64_t height, int64_t width) {
  FLAT_CHECK(height > 0 && width > 0, "pixel_rays: image size must be positive");
  const auto opts = cameras.intrinsics.options();
  const auto K = pixel_intrinsics(cameras.intrinsics, height, width);  // (V,4)
  const int64_t V = cameras.size();
  auto u = at::arange(width, opts).add_(0.5);   // pixel centres
  auto v = at::arange(height, opts).add_(0.5);
  auto fx = K.select(1, 0).view({V, 1, 1}), fy = K.select(1, 1).view({V, 1, 1});
  auto cx = K.select(1, 2).view({V, 1, 1}), cy = K.select(1, 3).view({V, 1, 1});
  auto x = ((u.view({1, 1, width}) - cx) / fx).expand({V, height, width});
  auto y = ((v.view({1, height, 1}) - cy) / fy).expand({V, height, width});
  auto dir_cam = at::stack({x, y, at::ones_like(x)}, -1);              // (V,H,W,3)
  auto R = cameras.c2w.narrow(1, 0, 3).narrow(2, 0, 3);                // (V,3,3)
  // R d per pixel; small_matmul, not einsum (whose bmm autocast casts to bf16).
  auto dir = small_matmul(R.view({V, 1, 1, 3, 3}), dir_cam.unsqueeze(-1)).squeeze(-1);
  dir = dir / dir.norm(2, -1, true);
  auto origin = cameras.c2w.narrow(1, 0, 3).select(2, 3).view({V, 1, 1, 3}).expand({V, height, width, 3});
  return {origin.contiguous(), dir.contiguous()};
}

}  // namespace flat::camera
