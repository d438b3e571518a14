#include "flat/mesh/soup_normal_targets.h"

#include <algorithm>
#include <vector>

namespace flat::mesh {

ViewTargets with_soup_normals(const primitives::TriangleSoup& soup, const ViewTargets& targets,
                              const render::RasterSettings& raster, double min_alpha, int64_t chunk) {
  at::NoGradGuard no_grad;
  std::vector<at::Tensor> normals;
  for (int64_t s = 0; s < targets.size(); s += chunk) {
    const auto views = at::arange(s, std::min(s + chunk, targets.size()), at::kLong);
    const auto out = render::rasterize(soup.vertices, soup.colors, soup.opacities, soup.sigmas,
                                       targets.cameras.index(views.to(targets.cameras.c2w.device())), targets.height(),
                                       targets.width(), raster);
    const auto covered = out.alpha >= min_alpha;
    normals.push_back(at::where(covered, out.normal / out.alpha.clamp_min(1e-6), at::zeros_like(out.normal)));
  }
  auto t = targets;
  t.normals = at::cat(normals).to(targets.rgb.device());
  return t;
}

}  // namespace flat::mesh
