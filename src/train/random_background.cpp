#include "flat/train/random_background.h"

#include <ATen/CPUGeneratorImpl.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::train {

at::Tensor use_random_background(pipeline::RenderedViews& views, const std::vector<double>& configured,
                                 uint64_t seed) {
  check_shape(views.rgb, {-1, 3, -1, -1}, "random background: rendered rgb", "(V,3,H,W)");
  check_shape(views.alpha, {views.rgb.size(0), 1, views.rgb.size(2), views.rgb.size(3)},
              "random background: rendered alpha", "(V,1,H,W) beside rgb");
  FLAT_CHECK(configured.size() == 3, "random background: the configured background needs 3 values, got " +
                                         std::to_string(configured.size()));
  const int64_t V = views.rgb.size(0);
  auto gen = at::make_generator<at::CPUGeneratorImpl>(seed);
  const at::Tensor colours = at::rand({V, 3}, gen, at::kFloat);
  const auto opts = views.rgb.options();
  const at::Tensor base = at::tensor(std::vector<float>(configured.begin(), configured.end()), at::kFloat);
  const at::Tensor shift = (colours - base.view({1, 3})).to(opts).view({V, 3, 1, 1});
  views.rgb = views.rgb + (1 - views.alpha) * shift;
  return colours;
}

}  // namespace flat::train
