// Post-optimisation (paper, appendix "Post Optimization"; Opaque Mesh
// Conversion, first step): per scene, starting from the feedforward
// triangles, fit positions (depth and shape), colour, opacity and sharpness
// to the input frames with the training objective, pruning weak or
// unsupported triangles as it goes. Any model's soup, a weak one included,
// is a valid start: nothing here needs the decoder.
#pragma once
#include <cstdint>
#include <vector>

#include "flat/core/config.h"
#include "flat/loss/objective.h"
#include "flat/mesh/view_targets.h"
#include "flat/primitives/triangle_soup.h"
#include "flat/render/rasterize.h"

namespace flat::mesh {

struct RefineOptions {
  int64_t steps = 250;          // paper: 250
  int64_t views_per_step = 4;   // views rendered per step (every view once per round)
  // Adam learning rates. Positions move in units of each triangle's own size
  // (its mean edge length at the start), so one rate suits near and far
  // triangles; colour and opacity are logits, sigma is log(sigma).
  double lr_position = 0.01;
  double lr_color = 0.02;
  double lr_opacity = 0.05;
  double lr_sigma = 0.01;
  // Pruning, every prune_every steps and at the end: opacity below
  // prune_opacity, or a largest blending weight below prune_weight over every
  // view since the last pruning (Triangle Splatting: 0.022).
  int64_t prune_every = 50;
  double prune_opacity = 0.05;
  double prune_weight = 0.02;
  uint64_t seed = 0;
  // Defaults: L2 only (LPIPS when lpips_weights is set, depth / normal terms
  // when their weights are > 0 and the targets hold the maps).
  loss::LossConfig loss = [] {
    loss::LossConfig c;
    c.lambda_perc = 0;
    c.lambda_depth = 0;
    c.lambda_normal = 0;
    c.lambda_opacity = 0;
    return c;
  }();
  render::RasterSettings raster;

  template <class V>
  void visit(V& v) {
    v.field("steps", steps, config::non_negative(), "post-optimisation steps (paper: 250)");
    v.field("views_per_step", views_per_step, config::positive(), "views rendered per step");
    v.field("lr_position", lr_position, config::non_negative(), "position step, in triangle sizes");
    v.field("lr_color", lr_color, config::non_negative(), "colour logit learning rate");
    v.field("lr_opacity", lr_opacity, config::non_negative(), "opacity logit learning rate");
    v.field("lr_sigma", lr_sigma, config::non_negative(), "log sigma learning rate");
    v.field("prune_every", prune_every, config::positive(), "steps between prunings");
    v.field("prune_opacity", prune_opacity, config::range(0.0, 1.0), "prune below this opacity");
    v.field("prune_weight", prune_weight, config::range(0.0, 1.0), "prune below this largest blending weight");
  }
};

struct RefineReport {
  int64_t steps = 0, triangles_before = 0, triangles_after = 0;
  std::vector<double> losses;  // objective per step
  double seconds = 0;
};

// start: one scene (vertices (N,3,3), colors (N,3) RGB, opacities, sigmas),
// on the targets' device. Returns the refined, pruned soup (detached).
// Throws flat::Error when pruning would leave no triangle.
primitives::TriangleSoup refine_soup(const primitives::TriangleSoup& start, const ViewTargets& targets,
                                     const RefineOptions& options, RefineReport* report = nullptr);

// Mean edge length per triangle (N,1,1): the unit refine_soup moves positions in.
at::Tensor triangle_sizes(const at::Tensor& vertices);

// The logit of p clamped to [1e-4, 1 - 1e-4]: opacity and colour parameters.
at::Tensor inverse_sigmoid(const at::Tensor& p);

}  // namespace flat::mesh
