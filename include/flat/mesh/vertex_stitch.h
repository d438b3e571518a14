// Stitching (paper, Opaque Mesh Conversion): boundary vertices that are each
// other's nearest boundary vertex, closer than a distance, are merged into
// one (at their midpoint, colours averaged), so that separate triangles
// become a connected mesh. The distance is local: distance_factor times the
// vertex's own scale (the mean edge length of its faces), the smaller of the
// pair's, so that near (small) triangles are not crushed by a threshold made
// for far (large) ones. Nearest neighbours come from a KD-tree
// (nanoflann). Faces that the merge collapses are removed.
//
// Colours live on the vertices, so a merge averages them: vertices whose
// colours differ by more than max_color_distance are not partners, and a
// colour edge stays an open seam (as texture seams split vertices in any
// engine mesh) instead of being blurred.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

#include "flat/primitives/indexed_mesh.h"

namespace flat::mesh {

struct StitchOptions {
  double distance_factor = 0.5;  // of the local edge length; pairs farther apart stay open
  double max_color_distance = 0.15;  // RGB Euclidean; <= 0: colours are not compared
  int64_t rounds = 10;      // at most; stops when a round merges nothing (a corner of k triangles needs several)
};

struct StitchReport {
  int64_t merged_pairs = 0, collapsed_faces = 0, rounds_run = 0;
};

// Boundary vertices: those on an edge that exactly one face uses. (V,) bool.
at::Tensor boundary_vertices(const primitives::IndexedMesh& mesh);

// Each vertex's scale (V,): the mean edge length of the faces using it.
at::Tensor vertex_scales(const primitives::IndexedMesh& mesh);

// For each vertex in `candidates` (V,) bool, its nearest candidate vertex that
// does not share a face with it, whose colour is within max_color_distance
// (<= 0: any) and that is no further than both vertices' radius (V,); else
// -1. (V,) int64 (entries of non-candidates are -1).
at::Tensor nearest_partners(const primitives::IndexedMesh& mesh, const at::Tensor& candidates, const at::Tensor& radius,
                            double max_color_distance = 0);

primitives::IndexedMesh stitch_boundary_vertices(const primitives::IndexedMesh& mesh, const StitchOptions& options,
                                                 StitchReport* report = nullptr);

}  // namespace flat::mesh
