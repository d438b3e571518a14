// Post-optimisation lowers the photometric loss of a perturbed soup, prunes
// what no view sees, and its optimiser keeps the moments of surviving rows.
#include <torch/torch.h>

#include "flat/mesh/prunable_adam.h"
#include "flat/mesh/refine.h"
#include "flat/render/rasterize.h"
#include "render/render_scenes.h"
#include "test_support.h"

using namespace flat;

namespace {

// Targets rendered from a reference soup by 4 cameras at 24x32.
mesh::ViewTargets targets_of(const test::Soup& s, int64_t views = 4) {
  const auto cams = test::test_cameras(views);
  render::RasterSettings raster;
  const auto out = render::rasterize(s.vertices, s.colors, s.opacities, s.sigmas, cams, 24, 32, raster);
  return {out.rgb.detach(), {}, {}, cams};
}

primitives::TriangleSoup soup_of(const test::Soup& s) { return {s.vertices, s.colors, s.opacities, s.sigmas}; }

double mean(const std::vector<double>& v, size_t from, size_t to) {
  double sum = 0;
  for (size_t i = from; i < to; ++i) sum += v[i];
  return sum / double(to - from);
}

}  // namespace

TEST_CASE("post-optimisation lowers the photometric loss of a perturbed soup", "[mesh]") {
  const auto reference = test::random_soup(40, torch::kFloat, 3);
  const auto targets = targets_of(reference);
  // Start: the same triangles with shuffled colours, moved, at half opacity.
  auto start = reference;
  start.colors = reference.colors.roll(7, 0);
  start.vertices = reference.vertices + 0.1 * torch::randn_like(reference.vertices);
  start.opacities = torch::full_like(reference.opacities, 0.5);
  mesh::RefineOptions o;
  o.steps = 60;
  o.views_per_step = 2;
  o.prune_opacity = 0.0;
  o.prune_weight = 0.0;
  mesh::RefineReport r;
  const auto out = mesh::refine_soup(soup_of(start), targets, o, &r);
  REQUIRE(r.losses.size() == 60);
  const double first = mean(r.losses, 0, 4), last = mean(r.losses, 56, 60);
  INFO("loss over the first 4 steps " << first << ", over the last 4 " << last);
  CHECK(last < 0.5 * first);
  CHECK(out.vertices.size(0) == 40);
  CHECK(r.triangles_after == 40);
  CHECK_FALSE(out.vertices.requires_grad());
  CHECK(at::isfinite(out.vertices).all().item<bool>());
}

TEST_CASE("post-optimisation prunes triangles that no view sees and those below the opacity", "[mesh]") {
  const auto reference = test::random_soup(20, torch::kFloat, 5);
  const auto targets = targets_of(reference);
  auto start = reference;
  // Triangle 0 behind every camera, triangle 1 nearly transparent.
  start.vertices[0] = start.vertices[0] * torch::tensor({1.f, 1.f, -1.f});
  start.opacities[1] = 0.001f;
  mesh::RefineOptions o;
  o.steps = 4;
  o.views_per_step = 4;
  o.prune_every = 4;
  o.prune_opacity = 0.01;
  o.prune_weight = 0.001;
  o.lr_position = o.lr_color = o.lr_opacity = o.lr_sigma = 0.0;  // nothing moves: only pruning acts
  mesh::RefineReport r;
  const auto out = mesh::refine_soup(soup_of(start), targets, o, &r);
  CHECK(r.triangles_after <= 18);
  // The survivors are the other triangles, unchanged (zero learning rates).
  CHECK(out.vertices.size(0) == r.triangles_after);
  const auto kept_first = out.vertices[0];
  bool found = false;
  for (int64_t i = 2; i < 20; ++i) found |= torch::allclose(kept_first, start.vertices[i], 1e-5, 1e-6);
  CHECK(found);
  // Pruning everything is an error that says so.
  o.prune_opacity = 0.999;
  REQUIRE_THROWS_WITH(mesh::refine_soup(soup_of(start), targets, o), FLAT_CONTAINS("would remove every triangle"));
}

TEST_CASE("PrunableAdam keeps the surviving rows' moments", "[mesh]") {
  mesh::PrunableAdam adam({torch::zeros({4, 2})}, {0.1});
  // One step with row-dependent gradients.
  adam.param(0).mutable_grad() = torch::arange(8, torch::kFloat).reshape({4, 2});
  adam.step();
  const auto before = adam.param(0).detach().clone();
  adam.keep_rows(torch::tensor({1L, 3L}));
  CHECK(torch::equal(adam.param(0).detach(), before.index_select(0, torch::tensor({1L, 3L}))));
  // The next step with the same gradients moves the kept rows as the unpruned optimiser would.
  mesh::PrunableAdam whole({torch::zeros({4, 2})}, {0.1});
  for (int k = 0; k < 2; ++k) {
    whole.param(0).mutable_grad() = torch::arange(8, torch::kFloat).reshape({4, 2});
    whole.step();
  }
  adam.param(0).mutable_grad() = torch::arange(8, torch::kFloat).reshape({4, 2}).index_select(0, torch::tensor({1L, 3L}));
  adam.step();
  CHECK(torch::allclose(adam.param(0).detach(), whole.param(0).detach().index_select(0, torch::tensor({1L, 3L}))));
}
