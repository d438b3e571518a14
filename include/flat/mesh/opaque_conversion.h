// Opaque mesh conversion (paper, Method "Opaque Mesh Conversion", following
// MeshSplatting): a (refined) semi-transparent soup becomes an opaque,
// connected, indexed mesh that any engine draws.
//
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
// evaluation) with opaque_raster(): FLAT window with no support beyond the
// edges, sharpness sigma_end, opacity snap_opacity.
#pragma once
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "flat/mesh/refine.h"
#include "flat/primitives/indexed_mesh.h"

namespace flat::mesh {

struct OpaqueOptions {
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
  int64_t mesh_vertices = 0, mesh_faces = 0;
  double median_edge = 0;
  std::vector<double> selection_losses, repair_losses;
  // PSNR over the fitted views after each stage: selection, support, stitched, repaired.
  std::vector<std::pair<std::string, double>> stage_psnr;
  double seconds = 0;
};

// soup: one scene with RGB colours, on the targets' device. The mesh comes
// back on the CPU. Throws flat::Error when a stage leaves no triangle.
primitives::IndexedMesh convert_to_opaque_mesh(const primitives::TriangleSoup& soup, const ViewTargets& targets,
                                               const OpaqueOptions& options, ConversionReport* report = nullptr);

// How the mesh is drawn: the given settings with no window support beyond
// the edges (eps 0).
render::RasterSettings opaque_raster(const render::RasterSettings& base);
// The mesh as the soup that opaque_raster draws.
primitives::TriangleSoup opaque_render_soup(const primitives::IndexedMesh& mesh, const OpaqueOptions& options);

}  // namespace flat::mesh
