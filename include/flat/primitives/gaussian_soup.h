// A batch of world-space Gaussians: the 3DGS (3 scales) and 2DGS surfel (2
// scales) baselines of the paper's Table 1, the output of build_gaussians()
// and the input of gaussians::rasterize_gaussians / surfels::rasterize_surfels
// and the Gaussian PLY exporter. Layout as TriangleSoup: B scenes of N
// primitives, N = T * (H/2) * (W/2), frame-major then row then column.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

namespace flat::primitives {

struct GaussianSoup {
  at::Tensor means;      // (B,N,3) world, metres
  at::Tensor scales;     // (B,N,3) 3DGS or (B,N,2) 2DGS: standard deviations along the rotated axes, > 0
  at::Tensor rotations;  // (B,N,4) unit quaternions (w,x,y,z), world
  at::Tensor colors;     // (B,N,3) RGB in [0,1]
  at::Tensor opacities;  // (B,N) in [0,1]

  int64_t batch() const { return means.size(0); }
  int64_t size() const { return means.size(1); }
  int64_t scale_count() const { return scales.size(-1); }  // 3: 3DGS, 2: 2DGS

  // Scene b without the batch dimension. Views, no copy.
  GaussianSoup scene(int64_t b) const { return {means[b], scales[b], rotations[b], colors[b], opacities[b]}; }
};

}  // namespace flat::primitives
