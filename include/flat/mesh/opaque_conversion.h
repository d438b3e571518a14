// Opaque mesh conversion (paper, Method "Opaque Mesh Conversion", following
// MeshSplatting): a (refined) semi-transparent soup becomes an opaque,
// connected, indexed mesh that any engine draws. Two ways (conversion):
//
// "grid" (default, issue #44): the soup's rendered surface per fitted view
// becomes a grid mesh at the token grid (grid_step 2: one sample per 2x2
// pixel block corner), its depth re-solved from the soup's rendered normals
// (normal_guided_depth.h: grid_depth_weight, grid_max_step), fused over the
// views with each view's seam welded onto the mesh so far (view_fusion.h,
// seam_weld.h: fusion_weld); edge-connected
// pieces with fewer than min_component_faces faces are removed as floaters
// (floaters.h); then the repair (4. below) with two more terms: the mesh's
// rendered normals towards the soup's own rendered normals
// (soup_normal_targets.h; the soup's depth is too noisy at the pixel scale
// to give normals by itself) and normal consistency between faces sharing
// an edge (mesh_smoothness.h). Welding the paper's separate triangles
// (below) left them hanging on single vertices (issue #44: 1,025
// edge-connected pieces for 1,971 faces, held-out normal cosine 0.795 ->
// 0.653); the grid's faces share edges by construction.
//
// "stitch" (the paper's steps):
//   1. opacity selection (selection_steps, paper: 50): positions, colours and
//      opacities are fitted while one global sigma anneals linearly from
//      sigma_start (paper: 0.5) to sigma_end and an opacity floor rises from
//      0 to 1 (opacity = floor + (1 - floor) sigmoid(x), MeshSplatting's
//      device), so opacities end binary: kept triangles at 1, the rest pruned
//      on the way (opacity or blending weight too low);
//   2. triangles whose largest blending weight over every view is at or below
//      support_min are removed (MeshSplatting's final cleanup: 0.5), the rest
//      snap to snap_opacity;
//   3. stitching (vertex_stitch.h), local densification of the open border
//      (boundary_densify.h), stitching again, floater pruning (floaters.h);
//   4. repair (repair_steps): vertex positions and colours fitted again with
//      the topology fixed.
// Distances are relative: to the local triangle size (stitching) or to the
// soup's median edge length (densification, repair), so the defaults hold at
// any scene scale. The mesh is drawn (here, in repair and in the
// evaluation) with opaque_raster(): FLAT window with almost no support beyond
// the edges, sharpness sigma_end, opacity snap_opacity.
#pragma once
#include <chrono>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "flat/mesh/refine.h"
#include "flat/primitives/indexed_mesh.h"

namespace flat::mesh {

struct OpaqueOptions {
  std::string conversion = "grid";  // "grid" (view_fusion.h) | "stitch" (the paper's selection and stitching)
  int64_t grid_step = 2;            // grid: pixels per grid sample (2: the decoder's token grid of 2x2 blocks)
  double grid_max_stretch = 6.0;    // grid: open a face whose edge exceeds this many pixel footprints
  double fusion_depth_tolerance = 0.05;  // grid: relative depth within which a view's surface is already held
  double grid_depth_weight = 0.005;  // grid: pull towards each view's rendered depth against the soup's normals
                                     // (normal_guided_depth.h; 0: the depth as rendered, unguided)
  double grid_max_step = 0.3;        // grid: log-depth step beyond the normals' taken as a discontinuity
  bool fusion_weld = true;           // grid: each view's seam welded onto the rim of the mesh so far
  double repair_smoothness = 0.05;  // weight of the normal-consistency term in the repair (0 = photometric only)
  double repair_soup_normals = 0.1; // grid: weight of the repair's normal term towards the soup's rendered normals
  int64_t selection_steps = 50;   // paper: 50
  double sigma_start = 0.5;       // paper: 0.5
  double sigma_end = 0.01;        // sharp: the window is ~1 inside, 0 outside
  int64_t selection_prune_every = 10;
  double selection_prune_opacity = 0.1;
  double selection_prune_weight = 0.02;
  double support_min = 0.5;
  double snap_opacity = 0.9999;
  double stitch_distance = 0.75;  // of the local edge length (vertex_stitch.h)
  double stitch_color_distance = 0.15;  // RGB: vertices further apart in colour stay an open seam
  int64_t stitch_rounds = 10;    // until nothing merges, at most this many
  double densify_edge = 2.0;      // split open faces with an open edge longer than this (median edge lengths)
  int64_t min_component_faces = 3;
  int64_t repair_steps = 200;
  int64_t views_per_step = 4;
  double lr_position = 0.01;      // selection: in triangle sizes
  double repair_lr_position = 0.002;  // repair: in median edge lengths (sharp windows give noisy position gradients)
  double lr_color = 0.02;
  double lr_opacity = 0.05;
  uint64_t seed = 0;
  loss::LossConfig loss = RefineOptions{}.loss;
  render::RasterSettings raster;  // the selection stage's settings (sigma and opacity come from the schedule)

  template <class V>
  void visit(V& v) {
    v.field("conversion", conversion, config::one_of({"grid", "stitch"}), "grid (view fusion) | stitch (paper)");
    v.field("grid_step", grid_step, config::positive(), "grid: pixels per grid sample");
    v.field("grid_max_stretch", grid_max_stretch, config::positive(), "grid: longest edge in pixel footprints");
    v.field("fusion_depth_tolerance", fusion_depth_tolerance, config::non_negative(),
            "grid: relative depth tolerance of the coverage test");
    v.field("grid_depth_weight", grid_depth_weight, config::non_negative(),
            "grid: depth re-solved from the soup's normals, this pull towards the rendered depth (0 = off)");
    v.field("grid_max_step", grid_max_step, config::positive(), "grid: log-depth departure cut as a discontinuity");
    v.field("fusion_weld", fusion_weld, "grid: weld each view's seam onto the mesh so far");
    v.field("repair_smoothness", repair_smoothness, config::non_negative(), "repair: normal-consistency weight");
    v.field("repair_soup_normals", repair_soup_normals, config::non_negative(),
            "grid repair: weight of the term towards the soup's rendered normals");
    v.field("selection_steps", selection_steps, config::non_negative(), "opacity selection steps (paper: 50)");
    v.field("sigma_start", sigma_start, config::positive(), "global sigma at the start (paper: 0.5)");
    v.field("sigma_end", sigma_end, config::positive(), "global sigma at the end");
    v.field("support_min", support_min, config::range(0.0, 1.0), "remove at or below this largest weight");
    v.field("snap_opacity", snap_opacity, config::range(0.0, 1.0), "opacity of the survivors");
    v.field("stitch_distance", stitch_distance, config::non_negative(), "merge distance (local edge lengths)");
    v.field("stitch_color_distance", stitch_color_distance, config::non_negative(),
            "largest RGB distance of merged vertices (0 = any)");
    v.field("stitch_rounds", stitch_rounds, config::non_negative(), "stitching rounds");
    v.field("densify_edge", densify_edge, config::positive(), "split open edges longer than this");
    v.field("min_component_faces", min_component_faces, config::positive(), "remove smaller pieces");
    v.field("repair_steps", repair_steps, config::non_negative(), "repair steps");
    v.field("repair_lr_position", repair_lr_position, config::non_negative(), "repair position step (median edges)");
  }
};

struct ConversionReport {
  int64_t soup_triangles = 0, after_selection = 0, after_support = 0;
  int64_t stitched_pairs = 0, collapsed_faces = 0, densified_faces = 0, floater_faces = 0;
  int64_t grid_faces = 0, fused_faces = 0;  // grid conversion: every view's grid, and what the fusion kept
  int64_t welded_vertices = 0, unwelded_vertices = 0, weld_dropped_faces = 0;  // grid: the seams (seam_weld.h)
  int64_t mesh_vertices = 0, mesh_faces = 0;
  double median_edge = 0;
  std::vector<double> selection_losses, repair_losses;
  // PSNR over the fitted views after each stage: selection, support, stitched, repaired.
  std::vector<std::pair<std::string, double>> stage_psnr;
  std::vector<double> stage_seconds;  // wall time of each of those stages, its PSNR included
  double seconds = 0;
  // A stage ends: its PSNR and the time since the previous stage ended.
  void end_stage(const std::string& stage, double psnr);

 private:
  std::chrono::steady_clock::time_point stage_start_ = std::chrono::steady_clock::now();
};

// soup: one scene with RGB colours, on the targets' device. The mesh comes
// back on the CPU. Throws flat::Error when a stage leaves no triangle.
primitives::IndexedMesh convert_to_opaque_mesh(const primitives::TriangleSoup& soup, const ViewTargets& targets,
                                               const OpaqueOptions& options, ConversionReport* report = nullptr);

// How the mesh is drawn: the given settings with the FLAT window and almost
// no support beyond the edges (eps 0.01: shared edges stay closed).
render::RasterSettings opaque_raster(const render::RasterSettings& base);
// The mesh as the soup that opaque_raster draws.
primitives::TriangleSoup opaque_render_soup(const primitives::IndexedMesh& mesh, const OpaqueOptions& options);

}  // namespace flat::mesh
