// Gaussians drawn as triangles, for what only draws triangles (the GLB and the
// three.js viewer): each Gaussian becomes a flat fan of `segments` triangles
// over the ellipse of radius kEllipseSigmas standard deviations along its two
// largest axes, with its colour and opacity. An approximation for looking at a
// 3DGS / 2DGS scene, not a renderer: the metrics always come from the Gaussian
// rasterizers.
#pragma once
#include <cstdint>

#include "flat/primitives/gaussian_soup.h"
#include "flat/primitives/triangle_soup.h"

namespace flat::primitives {

inline constexpr double kEllipseSigmas = 1.5;

// One scene (no batch dimension). Triangle i*segments + j is fan segment j of
// Gaussian i; sigmas are 1 (the soup's window parameter).
TriangleSoup splat_ellipses(const GaussianSoup& scene, int64_t segments = 6);

}  // namespace flat::primitives
