#include "flat/camera/ray_embeddings.h"

namespace flat::camera {

namespace {
// (V,H,W,3) + (V,H,W,3) -> (V,6,H,W)
at::Tensor channels_first(const at::Tensor& a, const at::Tensor& b) {
  return at::cat({a, b}, -1).permute({0, 3, 1, 2}).contiguous();
}
}  // namespace

at::Tensor plucker_map(const Rays& rays) {
  return channels_first(at::cross(rays.origins, rays.directions, -1), rays.directions);
}

at::Tensor rppc_map(const Rays& rays) {
  const auto& o = rays.origins;
  const auto& d = rays.directions;
  auto closest = o - (o * d).sum(-1, true) * d;  // o - (o.d) d
  return channels_first(closest, d);
}

}  // namespace flat::camera
