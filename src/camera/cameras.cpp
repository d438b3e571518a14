#include "flat/camera/cameras.h"

#include "flat/core/small_matmul.h"
#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::camera {

void Cameras::check(const std::string& what) const {
  check_shape(intrinsics, {-1, 4}, what + " intrinsics", "(V,4) normalised fx,fy,cx,cy");
  check_shape(c2w, {intrinsics.size(0), 4, 4}, what + " camera-to-world", "(V,4,4)");
  FLAT_CHECK(intrinsics.is_floating_point() && c2w.is_floating_point(), what + ": cameras must be floating point");
  check_finite(intrinsics, what + " intrinsics");
  check_finite(c2w, what + " camera-to-world");
  FLAT_CHECK((intrinsics.narrow(1, 0, 2) > 0).all().item<bool>(), what + ": focal lengths must be positive");
}

Cameras Cameras::to(const at::Device& device) const { return {intrinsics.to(device), c2w.to(device)}; }

Cameras Cameras::index(const at::Tensor& indices) const {
  auto idx = indices.to(intrinsics.device(), at::kLong);
  return {intrinsics.index_select(0, idx), c2w.index_select(0, idx)};
}

at::Tensor pixel_intrinsics(const at::Tensor& normalised, int64_t height, int64_t width) {
  auto scale = at::tensor({double(width), double(height), double(width), double(height)},
                          normalised.options());
  return normalised * scale;
}

at::Tensor normalise_intrinsics(const at::Tensor& pixels, int64_t height, int64_t width) {
  auto scale = at::tensor({double(width), double(height), double(width), double(height)}, pixels.options());
  return pixels / scale;
}

at::Tensor world_to_camera(const at::Tensor& c2w) {
  // [R t; 0 1]^-1 = [R^T  -R^T t; 0 1]
  auto R = c2w.narrow(-2, 0, 3).narrow(-1, 0, 3);
  auto t = c2w.narrow(-2, 0, 3).narrow(-1, 3, 1);
  auto Rt = R.transpose(-1, -2);
  auto out = at::zeros_like(c2w);
  out.narrow(-2, 0, 3).narrow(-1, 0, 3).copy_(Rt);
  out.narrow(-2, 0, 3).narrow(-1, 3, 1).copy_(-small_matmul(Rt, t));  // fp32 under autocast too
  out.select(-2, 3).select(-1, 3).fill_(1);
  return out;
}

}  // namespace flat::camera
