// Gaussians as the binary little-endian PLY that the 3DGS ecosystem reads
// (the INRIA layout: viewers such as SuperSplat, gsplat's and nerfstudio's
// loaders):
//   element vertex N : float x, y, z                  mean (world, metres)
//                      float nx, ny, nz               0 (unused, kept for the readers that expect it)
//                      float f_dc_0, f_dc_1, f_dc_2   (rgb - 0.5) / C0, C0 = 0.28209479 (degree-0 SH)
//                      float opacity                  logit(opacity)
//                      float scale_0 .. scale_{K-1}   log(standard deviation), K = 3 (3DGS) or 2 (2DGS)
//                      float rot_0 .. rot_3           unit quaternion w, x, y, z
// 2DGS files carry two scales, as 2DGS' own exporter writes them.
#pragma once
#include <string>

#include "flat/primitives/gaussian_soup.h"

namespace flat::exporter {

// One scene (no batch dimension: means (N,3), scales (N,3) or (N,2), rotations
// (N,4), colors (N,3) in [0,1], opacities (N)). Writes atomically; throws
// flat::Error on bad shapes (naming the tensor) or non-finite values.
void write_gaussian_ply(const std::string& path, const primitives::GaussianSoup& scene);
// Reads what write_gaussian_ply writes (any property order, extra properties
// ignored; f_rest_* not supported); throws flat::Error naming the file and property.
primitives::GaussianSoup read_gaussian_ply(const std::string& path);

}  // namespace flat::exporter
