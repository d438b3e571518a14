// The refined soup's own normals as the repair's normal targets (issue #44).
// The soup's rendered depth is noisy at the pixel scale (texture leaks into
// it), so a mesh made from that depth has noisy normals (held-out normal
// cosine ~0.5 against the soup's ~0.8 on the tiny run's rooms); the soup's
// rendered normals, from its triangles' orientations, are what kept the
// geometry. Fitting the mesh's rendered normals to them in the repair
// carries the soup's geometry over without using any reference normals.
#pragma once
#include "flat/mesh/view_targets.h"
#include "flat/primitives/triangle_soup.h"
#include "flat/render/rasterize.h"

namespace flat::mesh {

// targets with .normals replaced by the soup's alpha-normalised, camera-space
// rendered normals (0 where the soup covers less than min_alpha: no target).
ViewTargets with_soup_normals(const primitives::TriangleSoup& soup, const ViewTargets& targets,
                              const render::RasterSettings& raster, double min_alpha = 0.5, int64_t chunk = 8);

}  // namespace flat::mesh
