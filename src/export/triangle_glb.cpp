// GLB writer/reader for triangle soups through tinygltf (docs/formats.md).
#include "flat/export/triangle_glb.h"

#include <array>
#include <cstring>
#include <vector>

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/export/srgb.h"
#include "gltf_buffers.h"

#if FLAT_WITH_GLTF
#include <tiny_gltf.h>  // Debian builds the implementation into libtinygltf.so
#endif

namespace flat::exporter {
namespace {

#if FLAT_WITH_GLTF

void check_scene(const primitives::TriangleSoup& soup) {
  check_shape(soup.vertices, {-1, 3, 3}, "triangle glb: vertices", "(N,3,3)");
  const int64_t n = soup.vertices.size(0);
  check_shape(soup.colors, {n, 3}, "triangle glb: colors", "(N,3)");
  check_shape(soup.opacities, {n}, "triangle glb: opacities", "(N)");
  check_shape(soup.sigmas, {n}, "triangle glb: sigmas", "(N)");
  FLAT_CHECK(n > 0, "triangle glb: no triangles (glTF accessors need at least one element)");
  FLAT_CHECK(3 * n <= int64_t(UINT32_MAX), "triangle glb: too many triangles for uint32 indices");
  // min/max of POSITION are required by glTF and would be meaningless with NaN.
  check_finite(soup.vertices, "triangle glb: vertices");
  check_finite(soup.colors, "triangle glb: colors");
  check_finite(soup.opacities, "triangle glb: opacities");
  check_finite(soup.sigmas, "triangle glb: sigmas");
}

using Mat4 = std::array<double, 16>;  // column-major, as glTF

Mat4 identity() { return {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1}; }

Mat4 mul(const Mat4& a, const Mat4& b) {
  Mat4 c{};
  for (int col = 0; col < 4; ++col)
    for (int row = 0; row < 4; ++row)
      for (int k = 0; k < 4; ++k) c[col * 4 + row] += a[k * 4 + row] * b[col * 4 + k];
  return c;
}

// Rotation of 180 degrees about x: (x, y, z) -> (x, -y, -z). OpenCV world
// (y down, z forward) <-> glTF y-up; its own inverse.
const Mat4 kFlipYZ = {1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1};

// A node's local transform: its matrix, or T * R * S.
Mat4 local_transform(const tinygltf::Node& node) {
  if (node.matrix.size() == 16) {
    Mat4 m;
    std::copy(node.matrix.begin(), node.matrix.end(), m.begin());
    return m;
  }
  Mat4 t = identity(), r = identity(), s = identity();
  if (node.translation.size() == 3) for (int i = 0; i < 3; ++i) t[12 + i] = node.translation[i];
  if (node.scale.size() == 3) for (int i = 0; i < 3; ++i) s[5 * i] = node.scale[i];
  if (node.rotation.size() == 4) {
    const double x = node.rotation[0], y = node.rotation[1], z = node.rotation[2], w = node.rotation[3];
    r = {1 - 2 * (y * y + z * z), 2 * (x * y + z * w),     2 * (x * z - y * w),     0,
         2 * (x * y - z * w),     1 - 2 * (x * x + z * z), 2 * (y * z + x * w),     0,
         2 * (x * z + y * w),     2 * (y * z - x * w),     1 - 2 * (x * x + y * y), 0,
         0,                       0,                       0,                       1};
  }
  return mul(t, mul(r, s));
}

// World transform of the first node (depth first from the scene's roots) that
// instances mesh 0; identity when no node does.
bool find_mesh_node(const tinygltf::Model& m, int node, const Mat4& parent, int depth, Mat4& out) {
  if (node < 0 || node >= int(m.nodes.size()) || depth > 64) return false;
  const Mat4 world = mul(parent, local_transform(m.nodes[node]));
  if (m.nodes[node].mesh == 0) {
    out = world;
    return true;
  }
  for (int child : m.nodes[node].children)
    if (find_mesh_node(m, child, world, depth + 1, out)) return true;
  return false;
}

// Element i, component c of an accessor as double, with every bound checked
// once up front.
class AccessorView {
 public:
  AccessorView(const tinygltf::Model& m, int index, int type, const std::string& what, const std::string& path)
      : what_(path + ": " + what) {
    FLAT_CHECK(index >= 0 && index < int(m.accessors.size()), what_ + ": accessor " + std::to_string(index) +
                                                                  " does not exist");
    const tinygltf::Accessor& a = m.accessors[index];
    FLAT_CHECK(!a.sparse.isSparse, what_ + ": sparse accessors are not supported");
    FLAT_CHECK(type < 0 || a.type == type, what_ + ": accessor has the wrong type (" + std::to_string(a.type) +
                                               ", expected " + std::to_string(type) + ")");
    FLAT_CHECK(!a.normalized, what_ + ": normalized integer accessors are not supported (need float)");
    FLAT_CHECK(a.bufferView >= 0 && a.bufferView < int(m.bufferViews.size()), what_ + ": no bufferView");
    const tinygltf::BufferView& v = m.bufferViews[a.bufferView];
    FLAT_CHECK(v.buffer >= 0 && v.buffer < int(m.buffers.size()), what_ + ": bufferView without a buffer");
    const auto& data = m.buffers[v.buffer].data;
    component_ = a.componentType;
    size_ = size_t(tinygltf::GetComponentSizeInBytes(uint32_t(component_)));
    comps_ = size_t(tinygltf::GetNumComponentsInType(uint32_t(a.type)));
    FLAT_CHECK(size_ > 0 && comps_ > 0, what_ + ": unknown component or element type");
    stride_ = v.byteStride ? v.byteStride : size_ * comps_;
    count_ = a.count;
    const size_t span = count_ == 0 ? 0 : stride_ * (count_ - 1) + size_ * comps_;
    FLAT_CHECK(v.byteOffset + v.byteLength <= data.size() && a.byteOffset + span <= v.byteLength,
               what_ + ": accessor runs past its bufferView or buffer");
    base_ = data.data() + v.byteOffset + a.byteOffset;
  }
  size_t count() const { return count_; }
  int component() const { return component_; }
  double get(size_t i, size_t c) const {
    const unsigned char* p = base_ + i * stride_ + c * size_;
    switch (component_) {
      case TINYGLTF_COMPONENT_TYPE_FLOAT: { float f; std::memcpy(&f, p, 4); return f; }
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: { uint32_t u; std::memcpy(&u, p, 4); return u; }
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: { uint16_t u; std::memcpy(&u, p, 2); return u; }
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: return *p;
      default: fail(what_ + ": unsupported component type " + std::to_string(component_));
    }
  }
  void require_float() const {
    FLAT_CHECK(component_ == TINYGLTF_COMPONENT_TYPE_FLOAT, what_ + ": must be float (component type 5126), is " +
                                                                std::to_string(component_));
  }

 private:
  std::string what_;
  const unsigned char* base_ = nullptr;
  int component_ = 0;
  size_t size_ = 0, comps_ = 0, stride_ = 0, count_ = 0;
};

#else

constexpr const char* kNoGltf = "built without tinygltf (Debian libtinygltf-dev); the PLY export still works";

#endif  // FLAT_WITH_GLTF

}  // namespace

bool glb_export_available() { return FLAT_WITH_GLTF != 0; }

#if !FLAT_WITH_GLTF

void write_triangle_glb(const std::string& path, const primitives::TriangleSoup&) { fail(path + ": " + kNoGltf); }
primitives::TriangleSoup read_triangle_glb(const std::string& path) { fail(path + ": " + kNoGltf); }

#else

void write_triangle_glb(const std::string& path, const primitives::TriangleSoup& soup) {
  check_scene(soup);
  const int64_t n = soup.vertices.size(0);
  const auto cpu = [](const at::Tensor& t) { return t.detach().to(at::kCPU, at::kFloat).contiguous(); };
  const at::Tensor v = cpu(soup.vertices), c = cpu(soup.colors).clamp(0, 1), o = cpu(soup.opacities).clamp(0, 1),
                   s = cpu(soup.sigmas);
  const float* vp = v.data_ptr<float>();
  const float* cp = c.data_ptr<float>();
  const float* op = o.data_ptr<float>();
  const float* sp = s.data_ptr<float>();
  const size_t nv = size_t(3 * n);
  std::vector<float> colours(4 * nv), sigmas(nv);
  std::vector<uint32_t> indices(nv);
  std::vector<double> lo = {vp[0], vp[1], vp[2]}, hi = lo;
  for (size_t i = 0; i < size_t(n); ++i) {
    const float rgba[4] = {srgb_to_linear(cp[3 * i]), srgb_to_linear(cp[3 * i + 1]), srgb_to_linear(cp[3 * i + 2]),
                           op[i]};
    for (size_t k = 0; k < 3; ++k) {
      const size_t j = 3 * i + k;
      std::memcpy(&colours[4 * j], rgba, sizeof(rgba));
      sigmas[j] = sp[i];
      indices[j] = uint32_t(j);
      for (int d = 0; d < 3; ++d) {
        lo[d] = std::min(lo[d], double(vp[3 * j + d]));
        hi[d] = std::max(hi[d], double(vp[3 * j + d]));
      }
    }
  }

  tinygltf::Model m = new_glb_model();
  m.buffers[0].data.reserve(nv * (12 + 16 + 4 + 4));
  constexpr int kArray = TINYGLTF_TARGET_ARRAY_BUFFER, kElements = TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER;
  constexpr int kFloat = TINYGLTF_COMPONENT_TYPE_FLOAT;
  const int pos = add_accessor(m, add_view(m, vp, nv * 12, kArray), kFloat, TINYGLTF_TYPE_VEC3, nv);
  m.accessors[pos].minValues = lo;
  m.accessors[pos].maxValues = hi;
  const int col = add_accessor(m, add_view(m, colours.data(), nv * 16, kArray), kFloat, TINYGLTF_TYPE_VEC4, nv);
  const int sig = add_accessor(m, add_view(m, sigmas.data(), nv * 4, kArray), kFloat, TINYGLTF_TYPE_SCALAR, nv);
  const int idx = add_accessor(m, add_view(m, indices.data(), nv * 4, kElements),
                               TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT, TINYGLTF_TYPE_SCALAR, nv);

  tinygltf::Primitive prim;
  prim.mode = TINYGLTF_MODE_TRIANGLES;
  prim.attributes = {{"POSITION", pos}, {"COLOR_0", col}, {"_SIGMA", sig}};
  prim.indices = idx;
  // Baked radiance, blended by opacity.
  add_unlit_scene(m, prim, "flat_triangles", "BLEND");

  write_glb_file(path, m);
}

primitives::TriangleSoup read_triangle_glb(const std::string& path) {
  tinygltf::Model m;
  tinygltf::TinyGLTF loader;
  std::string err, warn;
  if (!loader.LoadBinaryFromFile(&m, &err, &warn, path))
    fail(path + ": cannot read GLB: " + (err.empty() ? std::string("unknown tinygltf error") : err));
  FLAT_CHECK(m.meshes.size() == 1 && m.meshes[0].primitives.size() == 1,
             path + ": expected one mesh with one primitive (FLAT layout), found " + std::to_string(m.meshes.size()) +
                 " meshes");
  const tinygltf::Primitive& prim = m.meshes[0].primitives[0];
  FLAT_CHECK(prim.mode == TINYGLTF_MODE_TRIANGLES || prim.mode == -1,
             path + ": primitive mode " + std::to_string(prim.mode) + " is not TRIANGLES (4)");
  for (const char* name : {"POSITION", "COLOR_0", "_SIGMA"})
    FLAT_CHECK(prim.attributes.count(name), path + ": primitive has no " + name + " attribute");
  AccessorView pos(m, prim.attributes.at("POSITION"), TINYGLTF_TYPE_VEC3, "POSITION", path);
  AccessorView col(m, prim.attributes.at("COLOR_0"), TINYGLTF_TYPE_VEC4, "COLOR_0", path);
  AccessorView sig(m, prim.attributes.at("_SIGMA"), TINYGLTF_TYPE_SCALAR, "_SIGMA", path);
  pos.require_float();
  col.require_float();
  sig.require_float();
  FLAT_CHECK(col.count() == pos.count() && sig.count() == pos.count(),
             path + ": COLOR_0 and _SIGMA must have one entry per POSITION");
  const size_t nv = pos.count();
  std::vector<uint32_t> index;
  if (prim.indices >= 0) {
    AccessorView ind(m, prim.indices, TINYGLTF_TYPE_SCALAR, "indices", path);
    FLAT_CHECK(ind.component() != TINYGLTF_COMPONENT_TYPE_FLOAT, path + ": indices must be unsigned integers");
    index.resize(ind.count());
    for (size_t i = 0; i < ind.count(); ++i) {
      const double k = ind.get(i, 0);
      FLAT_CHECK(k < double(nv), path + ": index " + std::to_string(uint64_t(k)) + " at " + std::to_string(i) +
                                      " out of range [0, " + std::to_string(nv) + ")");
      index[i] = uint32_t(k);
    }
  } else {
    index.resize(nv);
    for (size_t i = 0; i < nv; ++i) index[i] = uint32_t(i);
  }
  FLAT_CHECK(index.size() % 3 == 0, path + ": " + std::to_string(index.size()) + " indices is not a multiple of 3");

  // Our world = flip * (the mesh node's world transform) * position: our own
  // files carry exactly the flip, so their positions come back unchanged.
  Mat4 node = identity();
  const int scene = m.defaultScene >= 0 ? m.defaultScene : 0;
  if (scene < int(m.scenes.size()))
    for (int root : m.scenes[scene].nodes)
      if (find_mesh_node(m, root, identity(), 0, node)) break;
  const Mat4 to_ours = mul(kFlipYZ, node);

  const int64_t n = int64_t(index.size() / 3);
  primitives::TriangleSoup soup;
  soup.vertices = at::empty({n, 3, 3}, at::kFloat);
  soup.colors = at::empty({n, 3}, at::kFloat);
  soup.opacities = at::empty({n}, at::kFloat);
  soup.sigmas = at::empty({n}, at::kFloat);
  float* vp = soup.vertices.data_ptr<float>();
  float* cp = soup.colors.data_ptr<float>();
  float* op = soup.opacities.data_ptr<float>();
  float* sp = soup.sigmas.data_ptr<float>();
  for (int64_t i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) {
      const size_t j = index[size_t(3 * i + k)];
      const double p[3] = {pos.get(j, 0), pos.get(j, 1), pos.get(j, 2)};
      for (int d = 0; d < 3; ++d)
        vp[9 * i + 3 * k + d] =
            float(to_ours[d] * p[0] + to_ours[4 + d] * p[1] + to_ours[8 + d] * p[2] + to_ours[12 + d]);
    }
    const size_t first = index[size_t(3 * i)];
    for (int c = 0; c < 3; ++c) cp[3 * i + c] = linear_to_srgb(float(col.get(first, size_t(c))));
    op[i] = float(col.get(first, 3));
    sp[i] = float(sig.get(first, 0));
  }
  return soup;
}

#endif  // FLAT_WITH_GLTF

}  // namespace flat::exporter
