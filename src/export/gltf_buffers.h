// What our two GLB writers (triangle_glb.cpp, mesh_glb.cpp) share: the
// model of one buffer, buffer/bufferView/accessor appends, the unlit scene and
// the atomic write. Only for builds with tinygltf.
#pragma once
#if FLAT_WITH_GLTF
#include <string>

#include <tiny_gltf.h>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"

namespace flat::exporter {

// An empty glTF 2.0 model with the one buffer that add_view appends to.
inline tinygltf::Model new_glb_model() {
  tinygltf::Model m;
  m.asset.version = "2.0";
  m.asset.generator = "FLAT-C++";
  m.buffers.resize(1);
  return m;
}

// Appends `bytes` to the buffer and a bufferView over them; returns the view.
inline int add_view(tinygltf::Model& m, const void* bytes, size_t size, int target) {
  auto& data = m.buffers[0].data;
  tinygltf::BufferView view;
  view.buffer = 0;
  view.byteOffset = data.size();
  view.byteLength = size;
  view.target = target;
  data.insert(data.end(), static_cast<const unsigned char*>(bytes), static_cast<const unsigned char*>(bytes) + size);
  m.bufferViews.push_back(view);
  return int(m.bufferViews.size()) - 1;
}

inline int add_accessor(tinygltf::Model& m, int view, int component, int type, size_t count) {
  tinygltf::Accessor a;
  a.bufferView = view;
  a.byteOffset = 0;
  a.componentType = component;
  a.type = type;
  a.count = count;
  m.accessors.push_back(a);
  return int(m.accessors.size()) - 1;
}

// One mesh of one primitive (material 0), an unlit double-sided material with
// `alpha_mode` ("BLEND" | "OPAQUE"), and one root node rotated 180 degrees
// about x: our OpenCV world (y down, z forward) shown in glTF's y-up.
inline void add_unlit_scene(tinygltf::Model& m, tinygltf::Primitive prim, const std::string& mesh_name,
                            const std::string& alpha_mode) {
  prim.material = 0;
  tinygltf::Mesh mesh;
  mesh.name = mesh_name;
  mesh.primitives.push_back(prim);
  m.meshes.push_back(mesh);
  // Baked radiance: no lighting (unlit), both sides.
  tinygltf::Material mat;
  mat.name = "flat_unlit";
  mat.pbrMetallicRoughness.metallicFactor = 0.0;
  mat.pbrMetallicRoughness.roughnessFactor = 1.0;
  mat.doubleSided = true;
  mat.alphaMode = alpha_mode;
  mat.extensions["KHR_materials_unlit"] = tinygltf::Value(tinygltf::Value::Object());
  m.materials.push_back(mat);
  m.extensionsUsed.push_back("KHR_materials_unlit");
  tinygltf::Node node;
  node.name = "flat_scene (OpenCV world; rotated to y-up)";
  node.mesh = 0;
  node.rotation = {1.0, 0.0, 0.0, 0.0};  // quaternion (x, y, z, w): 180 degrees about x
  m.nodes.push_back(node);
  tinygltf::Scene scene;
  scene.nodes = {0};
  m.scenes.push_back(scene);
  m.defaultScene = 0;
}

// Writes `m` as binary glTF (GLB) to `path`, all or nothing (AtomicFile).
inline void write_glb_file(const std::string& path, tinygltf::Model& m) {
  AtomicFile file(path);
  tinygltf::TinyGLTF writer;
  if (!writer.WriteGltfSceneToStream(&m, file.stream(), /*prettyPrint=*/false, /*writeBinary=*/true))
    fail(path + ": tinygltf could not write the GLB");
  file.commit();
}

}  // namespace flat::exporter

#endif  // FLAT_WITH_GLTF
