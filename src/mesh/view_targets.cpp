#include "flat/mesh/view_targets.h"

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::mesh {

namespace {
at::Tensor maybe(const at::Tensor& t, const std::function<at::Tensor(const at::Tensor&)>& f) {
  return t.defined() ? f(t) : t;
}
}  // namespace

ViewTargets ViewTargets::to(const at::Device& device) const {
  const auto move = [&](const at::Tensor& t) { return t.to(device, at::kFloat); };
  return {move(rgb), maybe(depth, move), maybe(normals, move), cameras.to(device)};
}

ViewTargets ViewTargets::index(const at::Tensor& views) const {
  const auto pick = [&](const at::Tensor& t) { return t.index_select(0, views.to(t.device())); };
  return {pick(rgb), maybe(depth, pick), maybe(normals, pick), cameras.index(views.to(cameras.c2w.device()))};
}

void ViewTargets::check(const std::string& what) const {
  check_shape(rgb, {-1, 3, -1, -1}, what + ": rgb", "(V,3,H,W)");
  const int64_t v = rgb.size(0), h = rgb.size(2), w = rgb.size(3);
  FLAT_CHECK(v > 0 && h > 0 && w > 0, what + ": no views");
  check_finite(rgb, what + ": rgb");
  if (depth.defined()) check_shape(depth, {v, 1, h, w}, what + ": depth", "(V,1,H,W)");
  if (normals.defined()) check_shape(normals, {v, 3, h, w}, what + ": normals", "(V,3,H,W)");
  cameras.check(what + ": cameras");
  FLAT_CHECK(cameras.size() == v, what + ": " + std::to_string(cameras.size()) + " cameras for " + std::to_string(v) +
                                       " views");
}

}  // namespace flat::mesh
