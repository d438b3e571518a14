// Triangles as Gaussians, for timing the three rasterizers on the same scene
// (flat_bench raster --primitives 3dgs|2dgs, and scripts/bench_gsplat.py for
// gsplat, which applies the same rule to the anchor's triangles): each
// triangle becomes one Gaussian at its centroid, axes (e1, e2, n) with
// e1 = normalize(v1 - v0), n = the face normal, e2 = n x e1; standard
// deviation = the triangle's inradius along e1 and e2 (so the 1-sigma ellipse
// is its incircle), and kThinAxis times that along n (3DGS only); its colour
// and opacity. Same count, positions and screen footprint as the triangles.
#pragma once
#include <cstdint>

#include "flat/primitives/gaussian_soup.h"
#include "flat/primitives/triangle_soup.h"

namespace flat::primitives {

inline constexpr double kThinAxis = 0.1;

// One scene (vertices (N,3,3), colors (N,3), opacities (N)); scale_count 3
// (3DGS) or 2 (2DGS). Degenerate triangles give a zero scale (refused by the
// rasterizers' checks).
GaussianSoup gaussians_from_triangles(const TriangleSoup& scene, int64_t scale_count);

}  // namespace flat::primitives
