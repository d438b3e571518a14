// One view's surface as a grid mesh: a vertex per valid pixel (its depth
// unprojected through the pixel centre), two triangles per 2x2 pixel quad.
// Neighbouring quads share their vertices and edges by construction, which
// is what stitching separate soup triangles never achieved (issue #44: the
// stitched soup was 1,025 edge-connected pieces for 1,971 faces). Quads that
// span a depth discontinuity are left open: a triangle is dropped when one of
// its edges is longer than max_stretch times the pixel's footprint at its
// depth (z / f), so walls seen at a grazing angle stay, object borders open.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

#include "flat/primitives/indexed_mesh.h"

namespace flat::mesh {

struct DepthGridOptions {
  double max_stretch = 6.0;  // longest edge, in pixel footprints (z / f) at the triangle's mean depth
};

// depth (H,W) z-depth (<= 0: no surface), rgb (3,H,W) in [0,1], valid (H,W)
// bool, intrinsics (4) normalised (fx/W, fy/H, cx/W, cy/H), c2w (4,4).
// skip (H,W) bool or undefined: triangles whose three vertices are all
// skipped are not made (another view already holds that surface). Winding
// as the soup's: the normal faces the camera. Unused vertices are dropped.
primitives::IndexedMesh depth_grid_mesh(const at::Tensor& depth, const at::Tensor& rgb, const at::Tensor& valid,
                                        const at::Tensor& intrinsics, const at::Tensor& c2w,
                                        const DepthGridOptions& options, const at::Tensor& skip = {});

}  // namespace flat::mesh
