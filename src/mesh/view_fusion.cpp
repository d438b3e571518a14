#include "flat/mesh/view_fusion.h"

#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "flat/core/error.h"
#include "flat/core/progress.h"
#include "flat/mesh/normal_guided_depth.h"
#include "flat/mesh/seam_weld.h"

namespace flat::mesh {

std::vector<int64_t> fusion_order(int64_t views) {
  std::vector<int64_t> order;
  const int64_t mid = views / 2;
  if (views > 0) order.push_back(mid);
  for (int64_t d = 1; int64_t(order.size()) < views; ++d) {
    if (mid + d < views) order.push_back(mid + d);
    if (mid - d >= 0) order.push_back(mid - d);
  }
  return order;
}

primitives::IndexedMesh fuse_view_grids(const primitives::TriangleSoup& soup, const ViewTargets& targets,
                                        const render::RasterSettings& soup_raster, const ViewFusionOptions& o,
                                        ViewFusionReport* report) {
  FLAT_CHECK(o.grid_step >= 1, fmt::format("view fusion: grid_step must be >= 1, got {}", o.grid_step));
  at::NoGradGuard no_grad;
  // Samples at the corners of grid_step x grid_step blocks, the image's
  // border included (x = 0, step, ..., W in pixels): sampling at block
  // centres would leave half a block uncovered around every view's rim.
  const int64_t H = targets.height() / o.grid_step + 1, W = targets.width() / o.grid_step + 1;
  const double step = double(o.grid_step);
  const auto device = soup.vertices.device();
  ViewFusionReport r;
  r.views = targets.size();
  // Accumulated on the CPU; each view's faces offset by the vertices before it.
  primitives::IndexedMesh fused{at::zeros({0, 3}, at::kFloat), at::zeros({0, 3}, at::kFloat),
                                at::zeros({0, 3}, at::kLong)};
  // Minutes at the paper's size (37 views of 432x768: 204 s for the whole
  // conversion, 2026-11-28): a line with the rate and ETA.
  Progress progress("view fusion", targets.size());
  for (int64_t v : fusion_order(targets.size())) {
    const auto view = at::tensor({v}, at::kLong);
    auto cam = targets.cameras.index(view.to(targets.cameras.c2w.device()));
    // The same camera with its pixel centres on the block corners: u_grid + 0.5 = x / step.
    const auto k = camera::pixel_intrinsics(cam.intrinsics, targets.height(), targets.width()) / step;
    const auto shift = at::tensor({0.0f, 0.0f, 0.5f, 0.5f}, k.options());
    cam.intrinsics = camera::normalise_intrinsics(k + shift, H, W);
    const auto out = render::rasterize(soup.vertices, soup.colors, soup.opacities, soup.sigmas, cam, H, W, soup_raster);
    const auto alpha = out.alpha[0][0].cpu();
    // The first surface (where transmittance crosses 0.5) where there is one, so that silhouettes do not
    // blend the foreground into the wall behind; else the alpha-normalised depth of a thinner cover.
    const auto median = out.median_depth[0][0].cpu();
    auto depth = at::where(median > 0, median, out.depth[0][0].cpu() / alpha.clamp_min(1e-6));
    // The surface's own colour: the background's share taken out, then un-blended.
    const auto bg = at::tensor(soup_raster.background, at::kFloat).reshape({3, 1, 1});
    const auto rgb = ((out.rgb[0].cpu() - (1 - alpha) * bg) / alpha.clamp_min(1e-6)).clamp(0, 1);
    const auto valid = (alpha >= o.min_alpha) & (depth > 0);
    if (o.normal_guided) {
      const auto normals = out.normal[0].cpu() / alpha.clamp_min(1e-6);
      depth = normal_guided_depth(depth, normals, valid, cam.intrinsics[0].cpu(), o.guided);
    }
    at::Tensor skip;
    if (fused.num_faces() > 0) {
      const auto drawn = primitives::soup_from_mesh(fused, o.mesh_opacity, o.mesh_sigma);
      const auto seen = render::rasterize(drawn.vertices.to(device), drawn.colors.to(device),
                                          drawn.opacities.to(device), drawn.sigmas.to(device), cam, H, W,
                                          o.mesh_raster);
      const auto held_alpha = seen.alpha[0][0].cpu(), held_depth = seen.median_depth[0][0].cpu();
      skip = (held_alpha >= 0.5) & ((held_depth - depth).abs() <= o.depth_tolerance * depth);
    }
    const auto all = depth_grid_mesh(depth, rgb, valid, cam.intrinsics[0].cpu(), cam.c2w[0].cpu(), o.grid);
    r.grid_faces += all.num_faces();
    const auto grid = skip.defined()
                          ? depth_grid_mesh(depth, rgb, valid, cam.intrinsics[0].cpu(), cam.c2w[0].cpu(), o.grid, skip)
                          : all;
    spdlog::debug("view fusion: view {}: {} of {} samples covered, {} grid faces, {} new", v,
                  valid.sum().item<int64_t>(), H * W, all.num_faces(), grid.num_faces());
    if (grid.num_faces() == 0) {
      progress.step(1, {{"faces", double(fused.num_faces())}});
      continue;
    }
    if (skip.defined() && o.weld) {
      SeamWeldReport wr;
      fused = weld_view_seam(fused, grid, skip, cam.intrinsics[0].cpu(), cam.c2w[0].cpu(),
                             {o.weld_radius, o.depth_tolerance}, &wr);
      r.welded_vertices += wr.welded_vertices;
      r.unwelded_vertices += wr.unwelded_vertices;
      r.dropped_faces += wr.dropped_faces;
    } else {
      fused = {at::cat({fused.vertices, grid.vertices}), at::cat({fused.colors, grid.colors}),
               at::cat({fused.faces, grid.faces + fused.num_vertices()})};
    }
    progress.step(1, {{"faces", double(fused.num_faces())}});
  }
  progress.finish();
  r.fused_faces = fused.num_faces();
  if (report) *report = r;
  return fused;
}

}  // namespace flat::mesh
