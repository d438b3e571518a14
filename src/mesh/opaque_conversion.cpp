#include "flat/mesh/opaque_conversion.h"

#include <chrono>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "flat/core/error.h"
#include "flat/core/progress.h"
#include "flat/mesh/boundary_densify.h"
#include "flat/mesh/floaters.h"
#include "flat/mesh/mesh_smoothness.h"
#include "flat/mesh/prunable_adam.h"
#include "flat/mesh/soup_normal_targets.h"
#include "flat/mesh/vertex_stitch.h"
#include "flat/mesh/view_fusion.h"
#include "flat/mesh/view_fitting.h"

namespace flat::mesh {

namespace {

// PSNR over every view of the targets, for the report's stage-by-stage trail.
double psnr_over_views(const primitives::TriangleSoup& soup, const ViewTargets& t, const render::RasterSettings& raster) {
  at::NoGradGuard no_grad;
  double mse = 0;
  for (int64_t s = 0; s < t.size(); s += 8) {
    const auto views = at::arange(s, std::min(s + 8, t.size()), at::kLong);
    const auto picked = t.index(views);
    const auto out = render::rasterize(soup.vertices, soup.colors, soup.opacities, soup.sigmas, picked.cameras,
                                       t.height(), t.width(), raster);
    mse += (out.rgb.clamp(0, 1) - picked.rgb).square().mean({1, 2, 3}).sum().item<double>();
  }
  return -10.0 * std::log10(std::max(mse / double(t.size()), 1e-20));
}

void require_some(int64_t n, const std::string& stage) {
  FLAT_CHECK(n > 0, "opaque conversion: " + stage + " left no triangle (the soup does not cover the views, or the "
                    "thresholds are too strict)");
}

// Stage 1: opacity selection with the sigma schedule and the rising floor.
primitives::TriangleSoup select_opaque(const primitives::TriangleSoup& start, const ViewTargets& targets,
                                       const OpaqueOptions& o, ConversionReport& r) {
  auto base = start.vertices.detach().to(at::kFloat);
  auto size = triangle_sizes(base);
  // The floor starts at 0, so the logits start at the soup's opacities.
  PrunableAdam adam({at::zeros_like(base), inverse_sigmoid(start.colors.detach().to(at::kFloat)),
                     inverse_sigmoid(start.opacities.detach().to(at::kFloat))},
                    {o.lr_position, o.lr_color, o.lr_opacity});
  const int64_t steps = o.selection_steps;
  const auto schedule = [&](int64_t step, double& sigma, double& floor) {
    const double t = steps > 0 ? double(step) / double(steps) : 1.0;
    sigma = o.sigma_start + (o.sigma_end - o.sigma_start) * t;
    floor = t;
  };
  const auto soup = [&](double sigma, double floor) {
    const int64_t n = adam.param(0).size(0);
    return primitives::TriangleSoup{base + size * adam.param(0), at::sigmoid(adam.param(1)),
                                    floor + (1 - floor) * at::sigmoid(adam.param(2)),
                                    at::full({n}, sigma, base.options())};
  };
  loss::Objective objective(o.loss, targets.rgb.device());
  ViewCycle cycle(targets.size(), o.views_per_step, o.seed);
  auto max_weight = at::zeros({base.size(0)}, base.options());
  Progress progress("opacity selection", steps);
  for (int64_t step = 1; step <= steps; ++step) {
    double sigma = 0, floor = 0;
    schedule(step - 1, sigma, floor);
    auto fit = fit_loss(soup(sigma, floor), targets, cycle.next(), objective, o.raster);
    fit.loss.total.backward();
    adam.step();
    adam.zero_grad();
    const double loss = fit.loss.total.item<double>();
    FLAT_CHECK(std::isfinite(loss), fmt::format("opaque conversion: the loss became {} at selection step {}", loss, step));
    r.selection_losses.push_back(loss);
    max_weight = at::maximum(max_weight, fit.max_weight.to(max_weight.device()));
    const bool covered = step * std::min(o.views_per_step, targets.size()) >= targets.size();
    if (step % o.selection_prune_every == 0 && step < steps) {
      const auto opacity = floor + (1 - floor) * at::sigmoid(adam.param(2).detach());
      auto keep = opacity >= o.selection_prune_opacity;
      if (covered) keep = keep & (max_weight >= o.selection_prune_weight);
      const auto idx = keep.nonzero().reshape({-1});
      require_some(idx.numel(), "opacity selection");
      adam.keep_rows(idx);
      base = base.index_select(0, idx);
      size = size.index_select(0, idx);
      max_weight = covered ? at::zeros({idx.numel()}, base.options()) : max_weight.index_select(0, idx);
    }
    progress.step(1, {{"loss", loss}, {"sigma", sigma}, {"triangles", double(base.size(0))}});
  }
  progress.finish();
  at::NoGradGuard no_grad;
  auto out = soup(o.sigma_end, 1.0);
  return {out.vertices.detach(), out.colors.detach(), out.opacities.detach(), out.sigmas.detach()};
}

// Stage 4: vertex positions and colours, topology fixed.
primitives::IndexedMesh repair(const primitives::IndexedMesh& mesh, const ViewTargets& targets, const OpaqueOptions& o,
                               ConversionReport& r) {
  const auto device = targets.rgb.device();
  const auto faces = mesh.faces.to(device);
  const auto base = mesh.vertices.to(device, at::kFloat);
  PrunableAdam adam({at::zeros_like(base), inverse_sigmoid(mesh.colors.to(device, at::kFloat))}, {o.repair_lr_position, o.lr_color});
  const double unit = r.median_edge;
  const auto current = [&] {
    return primitives::IndexedMesh{base + unit * adam.param(0), at::sigmoid(adam.param(1)), faces};
  };
  auto loss_config = o.loss;
  if (targets.normals.defined() && o.repair_soup_normals > 0) loss_config.lambda_normal = o.repair_soup_normals;
  loss::Objective objective(loss_config, device);
  const auto raster = opaque_raster(o.raster);
  ViewCycle cycle(targets.size(), o.views_per_step, o.seed + 1);
  const auto pairs = o.repair_smoothness > 0 ? edge_adjacent_face_pairs(mesh.faces) : at::zeros({0, 2}, at::kLong);
  Progress progress("mesh repair", o.repair_steps);
  for (int64_t step = 1; step <= o.repair_steps; ++step) {
    const auto m = current();
    auto fit = fit_loss(opaque_render_soup(m, o), targets, cycle.next(), objective, raster);
    auto total = fit.loss.total;
    if (o.repair_smoothness > 0) total = total + o.repair_smoothness * normal_consistency(m.vertices, faces, pairs);
    total.backward();
    adam.step();
    adam.zero_grad();
    const double loss = total.item<double>();
    FLAT_CHECK(std::isfinite(loss), fmt::format("opaque conversion: the loss became {} at repair step {}", loss, step));
    r.repair_losses.push_back(loss);
    progress.step(1, {{"loss", loss}});
  }
  progress.finish();
  at::NoGradGuard no_grad;
  const auto m = current();
  return {m.vertices.detach().cpu(), m.colors.detach().cpu(), mesh.faces.cpu()};
}

// The mesh drawn as its opaque soup on the targets' device, scored for the
// report's trail.
double mesh_psnr(const primitives::IndexedMesh& m, const ViewTargets& t, const OpaqueOptions& o) {
  const auto soup = opaque_render_soup(m, o);
  const auto d = t.rgb.device();
  return psnr_over_views({soup.vertices.to(d), soup.colors.to(d), soup.opacities.to(d), soup.sigmas.to(d)}, t,
                         opaque_raster(o.raster));
}

// Grid stages: the soup's surface per view on the token grid, fused; edge
// pieces too small to be surface removed.
primitives::IndexedMesh fused_grid_mesh(const primitives::TriangleSoup& soup, const ViewTargets& targets,
                                        const OpaqueOptions& o, ConversionReport& r) {
  ViewFusionOptions fo;
  fo.grid_step = o.grid_step;
  fo.depth_tolerance = o.fusion_depth_tolerance;
  fo.grid.max_stretch = o.grid_max_stretch;
  fo.mesh_raster = opaque_raster(o.raster);
  fo.mesh_opacity = o.snap_opacity;
  fo.mesh_sigma = o.sigma_end;
  fo.normal_guided = o.grid_depth_weight > 0;
  if (fo.normal_guided) fo.guided.depth_weight = o.grid_depth_weight;
  fo.guided.max_step = o.grid_max_step;
  fo.weld = o.fusion_weld;
  ViewFusionReport fr;
  auto mesh = fuse_view_grids(soup, targets, o.raster, fo, &fr);
  r.grid_faces = fr.grid_faces;
  r.fused_faces = fr.fused_faces;
  r.welded_vertices = fr.welded_vertices;
  r.unwelded_vertices = fr.unwelded_vertices;
  r.weld_dropped_faces = fr.dropped_faces;
  require_some(mesh.num_faces(), "the view-grid fusion");
  r.end_stage("fused grids", mesh_psnr(mesh, targets, o));
  mesh = remove_small_components(mesh, o.min_component_faces, &r.floater_faces, /*through_edges=*/true);
  require_some(mesh.num_faces(), "floater pruning");
  r.end_stage("floaters", mesh_psnr(mesh, targets, o));
  return mesh;
}

// Stage 2: the selected triangles snapped to the opaque opacity, those with
// too little support over the views removed.
primitives::TriangleSoup keep_supported(const primitives::TriangleSoup& selected, const ViewTargets& targets,
                                        const OpaqueOptions& o) {
  auto snapped = selected;
  snapped.opacities = at::full_like(selected.opacities, o.snap_opacity);
  const auto support = support_over_views(snapped, targets, opaque_raster(o.raster));
  const auto keep = (support > o.support_min).nonzero().reshape({-1});
  require_some(keep.numel(), fmt::format("removing triangles with support <= {}", o.support_min));
  return {selected.vertices.index_select(0, keep), selected.colors.index_select(0, keep),
          snapped.opacities.index_select(0, keep), selected.sigmas.index_select(0, keep)};
}

// Stitch stages 1-3 (the paper's): opacity selection, the support cleanup and
// the snap; then stitch, densify the open border, stitch again, drop floaters.
primitives::IndexedMesh stitched_mesh(const primitives::TriangleSoup& soup, const ViewTargets& targets,
                                      const OpaqueOptions& o, ConversionReport& r) {
  auto selected = select_opaque(soup, targets, o, r);
  r.after_selection = selected.vertices.size(0);
  r.end_stage("selection", psnr_over_views(selected, targets, o.raster));
  selected = keep_supported(selected, targets, o);
  r.after_support = selected.vertices.size(0);
  r.end_stage("support", psnr_over_views(selected, targets, opaque_raster(o.raster)));

  auto mesh = primitives::mesh_from_soup({selected.vertices.cpu(), selected.colors.cpu(), selected.opacities.cpu(),
                                          selected.sigmas.cpu()});
  const StitchOptions stitch{o.stitch_distance, o.stitch_color_distance, o.stitch_rounds};
  StitchReport sr;
  r.end_stage("as mesh", mesh_psnr(mesh, targets, o));
  mesh = stitch_boundary_vertices(mesh, stitch, &sr);
  r.stitched_pairs += sr.merged_pairs;
  r.collapsed_faces += sr.collapsed_faces;
  r.end_stage("stitch 1", mesh_psnr(mesh, targets, o));
  mesh = densify_boundary(mesh, o.densify_edge * r.median_edge, &r.densified_faces);
  mesh = stitch_boundary_vertices(mesh, stitch, &sr);
  r.stitched_pairs += sr.merged_pairs;
  r.collapsed_faces += sr.collapsed_faces;
  r.end_stage("stitch 2", mesh_psnr(mesh, targets, o));
  mesh = remove_small_components(mesh, o.min_component_faces, &r.floater_faces);
  require_some(mesh.num_faces(), "floater pruning");
  r.end_stage("floaters", mesh_psnr(mesh, targets, o));
  return mesh;
}

void log_conversion(const ConversionReport& r, const OpaqueOptions& o, int64_t views) {
  if (o.conversion == "grid")
    spdlog::info("opaque conversion (view grids): {} soup triangles -> {} grid faces over {} views -> {} fused "
                 "({} seam vertices welded, {} left unwelded, {} seam faces dropped) -> mesh of {} vertices, {} faces "
                 "({} floater faces removed), {:.1f} s",
                 r.soup_triangles, r.grid_faces, views, r.fused_faces, r.welded_vertices, r.unwelded_vertices,
                 r.weld_dropped_faces, r.mesh_vertices, r.mesh_faces, r.floater_faces, r.seconds);
  else
    spdlog::info("opaque conversion: {} soup triangles -> {} after selection -> {} with support > {} -> mesh of {} "
                 "vertices, {} faces ({} pairs stitched, {} faces collapsed, {} split, {} floater faces removed), "
                 "{:.1f} s",
                 r.soup_triangles, r.after_selection, r.after_support, o.support_min, r.mesh_vertices, r.mesh_faces,
                 r.stitched_pairs, r.collapsed_faces, r.densified_faces, r.floater_faces, r.seconds);
  std::string trail;
  for (size_t i = 0; i < r.stage_psnr.size(); ++i)
    trail += fmt::format("{}{} {:.2f} dB ({:.1f} s)", i ? ", " : "", r.stage_psnr[i].first, r.stage_psnr[i].second,
                         r.stage_seconds[i]);
  spdlog::info("opaque conversion, PSNR over the fitted views after each stage (and the stage's time): {}", trail);
}

}  // namespace

void ConversionReport::end_stage(const std::string& stage, double psnr) {
  const auto now = std::chrono::steady_clock::now();
  stage_psnr.emplace_back(stage, psnr);
  stage_seconds.push_back(std::chrono::duration<double>(now - stage_start_).count());
  stage_start_ = now;
}

render::RasterSettings opaque_raster(const render::RasterSettings& base) {
  auto s = base;
  s.window = "flat";
  // Almost no support beyond the edges, but not none: with eps 0 a pixel
  // centre exactly on an edge that two faces share is covered by neither
  // (the window is 0 on the edge), and a grid mesh's diagonals pass through
  // pixel centres of its own views (issue #44), a dotted crack in every quad.
  s.eps = 0.01;
  return s;
}

primitives::TriangleSoup opaque_render_soup(const primitives::IndexedMesh& mesh, const OpaqueOptions& o) {
  return primitives::soup_from_mesh(mesh, o.snap_opacity, o.sigma_end);
}

primitives::IndexedMesh convert_to_opaque_mesh(const primitives::TriangleSoup& soup, const ViewTargets& targets,
                                               const OpaqueOptions& o, ConversionReport* report) {
  const auto t0 = std::chrono::steady_clock::now();
  targets.check("mesh conversion targets");
  FLAT_CHECK(soup.colors.dim() == 2, "opaque conversion: expects RGB colours (N,3), got SH coefficients");
  FLAT_CHECK(o.sigma_end <= o.sigma_start, "opaque conversion: sigma_end must not exceed sigma_start");
  FLAT_CHECK(o.conversion == "grid" || o.conversion == "stitch",
             "opaque conversion: conversion must be grid or stitch, got " + o.conversion);
  o.raster.check();
  ConversionReport r;
  r.soup_triangles = soup.vertices.size(0);
  require_some(r.soup_triangles, "the input");
  r.median_edge = triangle_sizes(soup.vertices.detach()).median().item<double>();

  auto mesh = o.conversion == "grid" ? fused_grid_mesh(soup, targets, o, r) : stitched_mesh(soup, targets, o, r);

  // 4. Repair (grid: towards the soup's own normals as well as the frames).
  mesh = o.conversion == "grid" && o.repair_soup_normals > 0
             ? repair(mesh, with_soup_normals(soup, targets, o.raster), o, r)
             : repair(mesh, targets, o, r);
  r.end_stage("repaired", mesh_psnr(mesh, targets, o));
  r.mesh_vertices = mesh.num_vertices();
  r.mesh_faces = mesh.num_faces();
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  log_conversion(r, o, targets.size());
  if (report) *report = r;
  return mesh;
}

}  // namespace flat::mesh
