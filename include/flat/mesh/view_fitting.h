// The step that every fitting stage of the mesh module shares (refine.h,
// opaque_conversion.h): render some views of a soup and score them with the
// training objective (loss/objective.h), and the order the views come in.
#pragma once
#include <cstdint>
#include <random>

#include <ATen/ATen.h>

#include "flat/loss/objective.h"
#include "flat/mesh/view_targets.h"
#include "flat/primitives/triangle_soup.h"
#include "flat/render/rasterize.h"

namespace flat::mesh {

// Every view once per round, rounds shuffled, `per_step` views a step.
class ViewCycle {
 public:
  ViewCycle(int64_t views, int64_t per_step, uint64_t seed);
  at::Tensor next();  // (K,) int64 on the CPU, K = min(per_step, views)

 private:
  std::vector<int64_t> order_;
  size_t at_ = 0;
  int64_t per_step_;
  std::mt19937_64 rng_;
};

struct FitLoss {
  loss::LossResult loss;
  at::Tensor max_weight;  // (N,) largest blending weight over the rendered views (no gradient)
};

// soup: one scene (N,3,3) etc. on the targets' device; views: indices into
// targets. Depth / normal terms use the targets' maps when they have them.
FitLoss fit_loss(const primitives::TriangleSoup& soup, const ViewTargets& targets, const at::Tensor& views,
                 loss::Objective& objective, const render::RasterSettings& raster);

}  // namespace flat::mesh

namespace flat::mesh {

// Largest blending weight of each triangle over every view (N,), rendered
// `chunk` views at a time without gradient: the support that decides which
// triangles are removed.
at::Tensor support_over_views(const primitives::TriangleSoup& soup, const ViewTargets& targets,
                              const render::RasterSettings& raster, int64_t chunk = 8);

}  // namespace flat::mesh
