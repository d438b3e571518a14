#include "flat/mesh/refine.h"

#include <chrono>

#include <spdlog/spdlog.h>

#include "flat/core/error.h"
#include "flat/core/progress.h"
#include "flat/core/shape.h"
#include "flat/mesh/prunable_adam.h"
#include "flat/mesh/view_fitting.h"

namespace flat::mesh {

at::Tensor inverse_sigmoid(const at::Tensor& p) { return at::logit(p.clamp(1e-4, 1 - 1e-4)); }

at::Tensor triangle_sizes(const at::Tensor& v) {
  const auto e = (v - v.roll(1, 1)).norm(2, -1);  // (N,3) edge lengths
  return e.mean(1).clamp_min(1e-8).reshape({-1, 1, 1});
}

primitives::TriangleSoup refine_soup(const primitives::TriangleSoup& start, const ViewTargets& targets,
                                     const RefineOptions& o, RefineReport* report) {
  const auto t0 = std::chrono::steady_clock::now();
  targets.check("post-optimisation targets");
  check_shape(start.vertices, {-1, 3, 3}, "post-optimisation: vertices", "(N,3,3)");
  const int64_t n = start.vertices.size(0);
  check_shape(start.colors, {n, 3}, "post-optimisation: colors", "(N,3) RGB");
  FLAT_CHECK(n > 0, "post-optimisation: the soup has no triangles");
  o.raster.check();
  loss::Objective objective(o.loss, targets.rgb.device());

  // Parameters: position offsets in triangle sizes, colour / opacity logits, log sigma.
  auto base = start.vertices.detach().to(at::kFloat);
  auto size = triangle_sizes(base);
  PrunableAdam adam({at::zeros_like(base), inverse_sigmoid(start.colors.detach().to(at::kFloat)),
                     inverse_sigmoid(start.opacities.detach().to(at::kFloat)), start.sigmas.detach().to(at::kFloat).log()},
                    {o.lr_position, o.lr_color, o.lr_opacity, o.lr_sigma});
  const auto soup = [&] {
    return primitives::TriangleSoup{base + size * adam.param(0), at::sigmoid(adam.param(1)),
                                    at::sigmoid(adam.param(2)), at::exp(adam.param(3))};
  };

  RefineReport r;
  r.triangles_before = n;
  ViewCycle cycle(targets.size(), o.views_per_step, o.seed);
  auto max_weight = at::zeros({n}, base.options());
  std::vector<bool> seen(size_t(targets.size()), false);
  Progress progress("post-optimisation", o.steps);
  for (int64_t step = 1; step <= o.steps; ++step) {
    const auto views = cycle.next();
    auto fit = fit_loss(soup(), targets, views, objective, o.raster);
    fit.loss.total.backward();
    adam.step();
    adam.zero_grad();
    const double loss = fit.loss.total.item<double>();
    FLAT_CHECK(std::isfinite(loss), "post-optimisation: the loss became " + std::to_string(loss) + " at step " +
                                        std::to_string(step) + " (lower the learning rates)");
    r.losses.push_back(loss);
    max_weight = at::maximum(max_weight, fit.max_weight.to(max_weight.device()));
    for (int64_t i = 0; i < views.size(0); ++i) seen[size_t(views[i].item<int64_t>())] = true;

    if (step % o.prune_every == 0 || step == o.steps) {
      // The weight test only when every view was rendered since the last pruning.
      const bool all_seen = std::all_of(seen.begin(), seen.end(), [](bool b) { return b; });
      auto keep = at::sigmoid(adam.param(2).detach()) >= o.prune_opacity;
      if (all_seen) keep = keep & (max_weight >= o.prune_weight);
      const auto idx = keep.nonzero().reshape({-1});
      FLAT_CHECK(idx.numel() > 0, fmt::format("post-optimisation: pruning at step {} would remove every triangle "
                                              "(prune_opacity {}, prune_weight {})",
                                              step, o.prune_opacity, o.prune_weight));
      if (idx.numel() < adam.param(0).size(0)) {
        adam.keep_rows(idx);
        base = base.index_select(0, idx);
        size = size.index_select(0, idx);
      }
      if (all_seen) {
        max_weight = at::zeros({idx.numel()}, base.options());
        std::fill(seen.begin(), seen.end(), false);
      } else {
        max_weight = max_weight.index_select(0, idx);
      }
    }
    progress.step(1, {{"loss", loss}, {"triangles", double(adam.param(0).size(0))}});
  }
  progress.finish();
  at::NoGradGuard no_grad;
  auto out = soup();
  r.steps = o.steps;
  r.triangles_after = out.vertices.size(0);
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  spdlog::info("post-optimisation: {} steps, {} -> {} triangles, loss {:.5f} -> {:.5f}, {:.1f} s", o.steps, n,
               r.triangles_after, r.losses.empty() ? 0.0 : r.losses.front(),
               r.losses.empty() ? 0.0 : r.losses.back(), r.seconds);
  if (report) *report = r;
  return {out.vertices.detach(), out.colors.detach(), out.opacities.detach(), out.sigmas.detach()};
}

}  // namespace flat::mesh
