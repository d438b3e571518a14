// Triangle soup as binary little-endian PLY (layout in docs/formats.md):
//   element vertex 3N : float x, y, z            (world, metres)
//                       uchar red, green, blue, alpha (the face's colour and
//                       opacity, quantised: for readers that know only vertex colours)
//   element face N    : list uchar int vertex_indices (3 per face),
//                       float red, green, blue    (display values in [0,1], as the images),
//                       float opacity             ([0,1]),
//                       float sigma               (window sharpness, > 0)
// The face properties are the lossless source; our reader takes the colours
// from them and also reads files without the vertex colours (older files).
#pragma once
#include <string>

#include <ATen/ATen.h>

#include "flat/primitives/triangle_soup.h"

namespace flat::exporter {

// One scene (no batch dimension: vertices (N,3,3), colors (N,3) RGB,
// opacities (N), sigmas (N); primitives::TriangleSoup::scene(b) gives it).
// Writes atomically; throws flat::Error on bad shapes (naming the tensor).
void write_triangle_ply(const std::string& path, const primitives::TriangleSoup& scene);
// Throws flat::Error naming the file and the element/property at fault.
primitives::TriangleSoup read_triangle_ply(const std::string& path);

}  // namespace flat::exporter
