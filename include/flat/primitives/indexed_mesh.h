// An indexed triangle mesh: the opaque output of the mesh conversion
// (mesh/opaque_conversion.h) and the input of the mesh exporters. Unlike the
// soup (triangle_soup.h), faces share vertices, and colours live on vertices
// (what every engine reads).
#pragma once
#include <cstdint>
#include <string>

#include <ATen/ATen.h>

#include "flat/primitives/triangle_soup.h"

namespace flat::primitives {

struct IndexedMesh {
  at::Tensor vertices;  // (V,3) float32, world (metres, OpenCV axes as the soup)
  at::Tensor colors;    // (V,3) float32 display (sRGB) values in [0,1]
  at::Tensor faces;     // (F,3) int64 indices into vertices; winding as the soup's

  int64_t num_vertices() const { return vertices.size(0); }
  int64_t num_faces() const { return faces.size(0); }
};

// The soup as a mesh that shares nothing: 3N vertices, face n = (3n, 3n+1,
// 3n+2), each vertex coloured with its triangle's RGB colour (N,3).
IndexedMesh mesh_from_soup(const TriangleSoup& scene);

// The mesh as a soup the rasterizer draws: vertices gathered per face, face
// colour = the mean of its vertex colours, one opacity and sigma for all.
// Differentiable w.r.t. mesh.vertices and mesh.colors (index_select).
TriangleSoup soup_from_mesh(const IndexedMesh& mesh, double opacity, double sigma);

// Drops unused vertices and renumbers the faces (keeps their order).
IndexedMesh compact_vertices(const IndexedMesh& mesh);

// Throws flat::Error naming `what` on wrong shapes, dtypes, indices out of
// range, or non-finite positions.
void check_mesh(const IndexedMesh& mesh, const std::string& what);

}  // namespace flat::primitives
