// Triangle soup as a GLB (binary glTF 2.0) file, for viewers and DCC tools
// (layout in docs/formats.md, "Triangle soup: GLB"):
//   one mesh, one TRIANGLES primitive, vertices not shared (3N), indices
//   uint32 0..3N-1; POSITION float VEC3 (our world coordinates, unchanged);
//   COLOR_0 float VEC4 (colour converted sRGB -> linear, alpha = opacity);
//   _SIGMA float SCALAR (window sharpness, for the round trip);
//   material: KHR_materials_unlit, doubleSided, alphaMode BLEND;
//   one root node rotated 180 degrees about x, which turns our OpenCV world
//   (y down, z forward) into glTF's y-up convention for display.
// Needs tinygltf (Debian libtinygltf-dev); built without it, the functions
// throw flat::Error (the PLY export works in every build).
#pragma once
#include <string>

#include "flat/primitives/triangle_soup.h"

namespace flat::exporter {

bool glb_export_available();

// One scene: vertices (N,3,3), colors (N,3), opacities (N), sigmas (N), N >= 1,
// finite. Colours and opacities are clamped to [0,1] (glTF's range). Atomic.
void write_triangle_glb(const std::string& path, const primitives::TriangleSoup& scene);

// Reads our layout back (any indices, uint8/16/32; the node transforms are
// applied and the y-up rotation undone), colours converted linear -> sRGB and
// taken from each triangle's first vertex. Throws flat::Error naming the file
// and the part at fault.
primitives::TriangleSoup read_triangle_glb(const std::string& path);

}  // namespace flat::exporter
