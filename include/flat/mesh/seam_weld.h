// Welding a view's new grid onto the mesh the earlier views made (issue #44).
// The view fusion (view_fusion.h) adds a view's faces only where the mesh so
// far does not already show the surface; the faces on the seam reach one
// sample into the held part. Appended as they are, the two sheets overlap by
// that ring without sharing a vertex, so every view was a separate piece
// (146 vertex-connected components a room on average). Here the new grid's
// vertices that lie on held samples are replaced by the mesh's own rim
// vertices (those on an edge with one face) where one projects into the view
// within `radius` samples of it at a depth within depth_tolerance: one rim
// vertex to one grid vertex, nearest pairs first. Seam faces then end on the
// old rim, and two neighbouring welded corners that are a rim edge make the
// new face share that edge. A welded vertex goes back to its own position
// (for all its faces) when a face using it would collapse (two corners on one
// rim vertex), repeat a directed edge (flipped winding, or a duplicate), give
// an edge a third face, or turn more than max_turn from its own plane; those
// faces then overlap the rim as all seam faces did before. The result stays
// manifold and consistently wound where it was, and no seam face is lost.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

#include "flat/primitives/indexed_mesh.h"

namespace flat::mesh {

struct SeamWeldOptions {
  double radius = 1.0;            // in grid samples, in the new view's image
  double depth_tolerance = 0.05;  // relative z-depth difference in the new view
  double max_turn = 0.5;          // radians: a welded face may turn this far from its own plane (~29 degrees)
};

struct SeamWeldReport {
  int64_t welded_vertices = 0;    // grid vertices replaced by rim vertices
  int64_t unwelded_vertices = 0;  // candidates sent back to their own positions (a face broke a rule above)
  int64_t dropped_faces = 0;      // new faces that do not fit even on their own corners (not expected of a grid)
};

// mesh: the surface so far; grid: the new view's faces (on their own
// vertices); held (H,W) bool: the samples the mesh already shows in the new
// view; intrinsics (4) normalised for that H x W sample grid (centres at
// +0.5), c2w (4,4). Returns mesh followed by grid, welded, vertices compacted
// (the mesh's own vertices keep their indices). CPU.
primitives::IndexedMesh weld_view_seam(const primitives::IndexedMesh& mesh, const primitives::IndexedMesh& grid,
                                       const at::Tensor& held, const at::Tensor& intrinsics, const at::Tensor& c2w,
                                       const SeamWeldOptions& options = {}, SeamWeldReport* report = nullptr);

}  // namespace flat::mesh
