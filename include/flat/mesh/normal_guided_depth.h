// A view's depth re-integrated from the soup's rendered normals (issue #44).
// The soup's rendered depth carries the colour's texture at the pixel scale
// (checkerboards as ripples, and the median depth steps from one overlapping
// triangle to the next), and a grid mesh made of it at two pixels a sample
// tilts every face with that noise: on the held-out rooms the fused grids'
// normal cosine was 0.33 before the repair, the soup's own rendered normals
// 0.73. The soup's rendered normals are far steadier than its depth's slope,
// so the depth is solved again: each pair of neighbouring samples is asked
// to step in log depth as a plane with their mean normal would
// (log(n.r_p) - log(n.r_q), exact for a plane seen through rays r), each
// sample to stay near its rendered depth (depth_weight, against 1 per link),
// in least squares (conjugate gradients). Links across a discontinuity are
// cut: where the rendered depth steps by more than max_step in log depth
// beyond what the normal predicts (an object's rim against the wall behind),
// or where a ray meets the mean normal edge-on.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

namespace flat::mesh {

// The defaults were chosen on one held-out room (room_000002 of seed 1001)
// and checked on 15 more (docs/inference.md): the soup's median depth steps
// by 0.1 or more in log depth between neighbouring samples of one plane
// (scales of overlapping triangles), so a cut at 0.1 broke the planes into
// patches (fused-grid normal cosine 0.57, against 0.70 at 0.3); a pull of
// 0.05 towards that depth kept its ripples (0.63 against 0.70 at 0.005).
struct NormalGuidedDepthOptions {
  double depth_weight = 0.005;  // pull of a sample towards its rendered log depth, against 1 per neighbour link
  double max_step = 0.3;        // cut a link where the rendered log depth departs from the normals' step by more
  int64_t iterations = 300;     // conjugate-gradient iterations at most (stops at a relative residual of 1e-6)
};

// depth (H,W) z-depth, normals (3,H,W) camera space (any length; zero where
// unknown), valid (H,W) bool, intrinsics (4) normalised (fx/W, fy/H, cx/W,
// cy/H), pixel centres at +0.5. Returns (H,W) float: the solved depth on
// valid samples, the input elsewhere. A sample without a usable link keeps
// its depth.
at::Tensor normal_guided_depth(const at::Tensor& depth, const at::Tensor& normals, const at::Tensor& valid,
                               const at::Tensor& intrinsics, const NormalGuidedDepthOptions& options = {});

}  // namespace flat::mesh
