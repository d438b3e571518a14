// The opaque mesh as GLB through tinygltf (docs/formats.md, "Opaque mesh").
#include <cstdint>
#include <vector>

#include "flat/core/error.h"
#include "flat/export/mesh_files.h"
#include "flat/export/srgb.h"
#include "gltf_buffers.h"

namespace flat::exporter {

#if !FLAT_WITH_GLTF

void write_mesh_glb(const std::string& path, const primitives::IndexedMesh&) {
  fail(path + ": built without tinygltf (Debian libtinygltf-dev); the PLY and OBJ exports still work");
}

#else

void write_mesh_glb(const std::string& path, const primitives::IndexedMesh& mesh) {
  primitives::check_mesh(mesh, path);
  const int64_t nv = mesh.num_vertices(), nf = mesh.num_faces();
  FLAT_CHECK(nv > 0 && nf > 0, path + ": the mesh is empty (glTF accessors need at least one element)");
  FLAT_CHECK(nv <= int64_t(UINT32_MAX), path + ": too many vertices for uint32 indices");
  const auto v = mesh.vertices.detach().to(at::kCPU, at::kFloat).contiguous();
  const auto c = mesh.colors.detach().to(at::kCPU, at::kFloat).clamp(0, 1).contiguous();
  const auto f = mesh.faces.to(at::kCPU).to(at::kInt).contiguous();
  std::vector<float> linear(size_t(3 * nv));
  const float* cp = c.data_ptr<float>();
  for (size_t i = 0; i < linear.size(); ++i) linear[i] = srgb_to_linear(cp[i]);
  const auto lo = v.amin(0).to(at::kDouble), hi = v.amax(0).to(at::kDouble);

  tinygltf::Model m = new_glb_model();
  constexpr int kArray = TINYGLTF_TARGET_ARRAY_BUFFER, kElements = TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER;
  constexpr int kFloat = TINYGLTF_COMPONENT_TYPE_FLOAT;
  const int pos = add_accessor(m, add_view(m, v.data_ptr<float>(), size_t(nv) * 12, kArray), kFloat,
                               TINYGLTF_TYPE_VEC3, size_t(nv));
  m.accessors[pos].minValues = {lo[0].item<double>(), lo[1].item<double>(), lo[2].item<double>()};
  m.accessors[pos].maxValues = {hi[0].item<double>(), hi[1].item<double>(), hi[2].item<double>()};
  const int col =
      add_accessor(m, add_view(m, linear.data(), size_t(nv) * 12, kArray), kFloat, TINYGLTF_TYPE_VEC3, size_t(nv));
  const int idx = add_accessor(m, add_view(m, f.data_ptr<int32_t>(), size_t(nf) * 12, kElements),
                               TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT, TINYGLTF_TYPE_SCALAR, size_t(3 * nf));
  tinygltf::Primitive prim;
  prim.mode = TINYGLTF_MODE_TRIANGLES;
  prim.attributes = {{"POSITION", pos}, {"COLOR_0", col}};
  prim.indices = idx;
  add_unlit_scene(m, prim, "flat_mesh", "OPAQUE");

  write_glb_file(path, m);
}

#endif  // FLAT_WITH_GLTF

}  // namespace flat::exporter
