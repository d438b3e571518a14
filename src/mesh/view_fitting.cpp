#include "flat/mesh/view_fitting.h"

#include <algorithm>
#include <numeric>

#include "flat/pipeline/scene_pipeline.h"

namespace flat::mesh {

ViewCycle::ViewCycle(int64_t views, int64_t per_step, uint64_t seed)
    : order_(size_t(views)), per_step_(std::min(per_step, views)), rng_(seed) {
  std::iota(order_.begin(), order_.end(), 0);
  std::shuffle(order_.begin(), order_.end(), rng_);
}

at::Tensor ViewCycle::next() {
  std::vector<int64_t> out;
  while (int64_t(out.size()) < per_step_) {
    if (at_ == order_.size()) {
      std::shuffle(order_.begin(), order_.end(), rng_);
      at_ = 0;
    }
    // A view twice in one step only when a round ends mid-step; skip it then.
    const int64_t v = order_[at_++];
    if (std::find(out.begin(), out.end(), v) == out.end()) out.push_back(v);
  }
  return at::tensor(out, at::kLong);
}

FitLoss fit_loss(const primitives::TriangleSoup& soup, const ViewTargets& targets, const at::Tensor& views,
                 loss::Objective& objective, const render::RasterSettings& raster) {
  const auto picked = targets.index(views);
  const auto out = render::rasterize(soup.vertices, soup.colors, soup.opacities, soup.sigmas, picked.cameras,
                                     targets.height(), targets.width(), raster);
  const auto r = pipeline::normalise_by_alpha(out);
  loss::LossInputs in;
  in.rgb = r.rgb;
  in.target_rgb = picked.rgb;
  in.alpha = r.alpha;
  in.opacities = soup.opacities;
  const auto& cfg = objective.config();
  if (cfg.lambda_depth > 0) {
    in.depth = r.depth;
    in.target_depth = picked.depth;
  }
  if (cfg.lambda_normal > 0) {
    in.normal = r.normal;
    in.target_normal = picked.normals;
  }
  return {objective(in), out.max_weight};
}

}  // namespace flat::mesh

namespace flat::mesh {

at::Tensor support_over_views(const primitives::TriangleSoup& soup, const ViewTargets& targets,
                              const render::RasterSettings& raster, int64_t chunk) {
  at::NoGradGuard no_grad;
  auto best = at::zeros({soup.vertices.size(0)}, soup.vertices.options().dtype(at::kFloat));
  for (int64_t s = 0; s < targets.size(); s += chunk) {
    const auto views = at::arange(s, std::min(s + chunk, targets.size()), at::kLong);
    const auto out = render::rasterize(soup.vertices, soup.colors, soup.opacities, soup.sigmas,
                                       targets.cameras.index(views.to(targets.cameras.c2w.device())),
                                       targets.height(), targets.width(), raster);
    best = at::maximum(best, out.max_weight.to(best.device(), at::kFloat));
  }
  return best;
}

}  // namespace flat::mesh
