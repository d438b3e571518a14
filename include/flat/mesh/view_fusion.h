// Grid-structured conversion of a soup into a connected mesh (issue #44):
// the soup is rendered into every fitted view at the token grid (one sample
// per 2x2 pixel block, the resolution the decoder made its triangles at),
// each view's depth becomes a grid mesh (depth_grid_mesh.h) whose faces
// share edges by construction, and the views are fused greedily: the middle
// view first, then outwards, each adding only the faces whose surface the
// mesh so far does not already show in that view (rendered there, within a
// relative depth tolerance). Each view's depth is first re-solved from the
// soup's rendered normals (normal_guided_depth.h), and each view's seam is
// welded onto the rim of the mesh so far (seam_weld.h), so that the views
// make one surface, not sheets side by side. The soup's geometry (its
// rendered normals, its depth at larger scales) is what the mesh keeps,
// instead of the midpoints of stitched vertex pairs that bent the faces
// before.
#pragma once
#include <cstdint>

#include "flat/mesh/depth_grid_mesh.h"
#include "flat/mesh/normal_guided_depth.h"
#include "flat/mesh/seam_weld.h"
#include "flat/mesh/view_targets.h"
#include "flat/primitives/indexed_mesh.h"
#include "flat/primitives/triangle_soup.h"
#include "flat/render/rasterize.h"

namespace flat::mesh {

struct ViewFusionOptions {
  int64_t grid_step = 2;         // pixels per grid sample (2: the decoder's token grid)
  double min_alpha = 0.2;        // pixels the soup covers less than this have no surface
  double depth_tolerance = 0.05; // relative: a view's pixel is already held when the mesh shows a depth this close
  DepthGridOptions grid;
  bool normal_guided = true;       // each view's depth re-solved from the soup's normals (normal_guided_depth.h)
  NormalGuidedDepthOptions guided;
  bool weld = true;                // a view's seam vertices become the mesh's rim vertices (seam_weld.h)
  double weld_radius = 1.0;        // in samples; the weld's depth tolerance is depth_tolerance
  // How the mesh so far is drawn for the coverage test (opaque_conversion.h's opaque_raster).
  render::RasterSettings mesh_raster;
  double mesh_opacity = 0.9999, mesh_sigma = 0.01;
};

struct ViewFusionReport {
  int64_t views = 0, grid_faces = 0, fused_faces = 0;  // grid_faces: all views' grids before the coverage test
  int64_t welded_vertices = 0, unwelded_vertices = 0, dropped_faces = 0;  // seam_weld.h, summed over the views
};

// soup: one scene, drawn with soup_raster; targets: the fitted views (their
// cameras and size). Returns the fused mesh on the CPU.
primitives::IndexedMesh fuse_view_grids(const primitives::TriangleSoup& soup, const ViewTargets& targets,
                                        const render::RasterSettings& soup_raster, const ViewFusionOptions& options,
                                        ViewFusionReport* report = nullptr);

// The order views are fused in: the middle one, then alternately after and before it.
std::vector<int64_t> fusion_order(int64_t views);

}  // namespace flat::mesh
