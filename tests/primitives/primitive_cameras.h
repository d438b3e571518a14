// Cameras for the primitive builders' tests (ray_triangles, ray_gaussians).
#pragma once
#include <ATen/ATen.h>

#include "flat/camera/cameras.h"

namespace flat::test {

// V cameras with varied rotations, positions and (anisotropic) intrinsics.
inline flat::camera::Cameras make_cameras(int64_t V, at::ScalarType dtype = at::kFloat) {
  auto g = at::make_generator<at::CPUGeneratorImpl>(7);
  auto q = at::randn({V, 4}, g, at::kDouble);
  q = q / q.norm(2, -1, true);
  auto w = q.select(1, 0), x = q.select(1, 1), y = q.select(1, 2), z = q.select(1, 3);
  auto R = at::stack({1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                      2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                      2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}, -1).view({V, 3, 3});
  auto c2w = at::eye(4, at::kDouble).repeat({V, 1, 1});
  c2w.narrow(1, 0, 3).narrow(2, 0, 3).copy_(R);
  c2w.narrow(1, 0, 3).select(2, 3).copy_(at::randn({V, 3}, g, at::kDouble));
  auto K = at::empty({V, 4}, at::kDouble);
  K.select(1, 0).copy_(0.7 + 0.3 * at::rand({V}, g, at::kDouble));  // fx/W: up to ~70 deg FOV
  K.select(1, 1).copy_(0.9 + 0.3 * at::rand({V}, g, at::kDouble));
  K.select(1, 2).copy_(0.4 + 0.2 * at::rand({V}, g, at::kDouble));
  K.select(1, 3).copy_(0.4 + 0.2 * at::rand({V}, g, at::kDouble));
  return flat::camera::Cameras{K.to(dtype), c2w.to(dtype)};
}

}  // namespace flat::test
