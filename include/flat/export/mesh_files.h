// The opaque mesh (primitives/indexed_mesh.h) for engines and DCC tools
// (layouts in docs/formats.md, "Opaque mesh"). All three share vertices and
// carry colours on the vertices; all writes are atomic.
//   GLB: one TRIANGLES primitive, uint32 indices, POSITION float VEC3,
//        COLOR_0 float VEC3 (sRGB -> linear), unlit double-sided OPAQUE
//        material, y-up root node as the soup's GLB (triangle_glb.h).
//        Needs tinygltf (glb_export_available()).
//   PLY: binary little-endian; vertex x y z float, red green blue uchar;
//        face list uchar int vertex_indices.
//   OBJ: "v x y z r g b" (colours in [0,1], the vertex-colour extension that
//        Blender, trimesh and assimp read) and "f a b c" (1-based).
#pragma once
#include <string>

#include "flat/primitives/indexed_mesh.h"

namespace flat::exporter {

void write_mesh_glb(const std::string& path, const primitives::IndexedMesh& mesh);
void write_mesh_ply(const std::string& path, const primitives::IndexedMesh& mesh);
void write_mesh_obj(const std::string& path, const primitives::IndexedMesh& mesh);

}  // namespace flat::exporter
