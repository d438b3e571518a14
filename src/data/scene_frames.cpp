#include "flat/data/scene_frames.h"

#include <cstring>

#include "flat/core/error.h"
#include "flat/core/safetensors.h"
#include "flat/core/shape.h"
#include "flat/data/frame_io.h"
#include "flat/data/pack.h"

namespace flat::data {

namespace {

// Frames `indices` of the packed tensor `name` ((N,C,H,W)), as float32.
at::Tensor packed_slices(const safetensors::MappedFile& file, const std::string& name, int64_t channels,
                         const Scene& scene, const std::vector<int64_t>& indices) {
  const auto* entry = file.header().find(name);
  if (!entry) fail(file.path() + ": packed scene '" + scene.name + "' has no tensor '" + name + "'");
  at::ScalarType type;
  switch (entry->dtype) {
    case safetensors::DType::U8: type = at::kByte; break;
    case safetensors::DType::F16: type = at::kHalf; break;
    case safetensors::DType::F32: type = at::kFloat; break;
    default: fail(file.path() + ": tensor '" + name + "' has dtype " + std::string(safetensors::dtype_name(entry->dtype)) +
                  "; packs hold U8, F16 or F32");
  }
  const std::vector<int64_t> expect{scene.size(), channels, scene.height, scene.width};
  if (entry->shape != expect)
    fail(file.path() + ": tensor '" + name + "' has shape " + shape_str(entry->shape) + ", expected " +
         shape_str(expect) + " for scene '" + scene.name + "'");
  const size_t frame_bytes = size_t(channels * scene.height * scene.width) * safetensors::dtype_size(entry->dtype);
  at::Tensor out = at::empty({int64_t(indices.size()), channels, scene.height, scene.width}, type);
  const uint8_t* base = file.data(*entry);
  for (size_t k = 0; k < indices.size(); ++k)
    std::memcpy(static_cast<uint8_t*>(out.data_ptr()) + k * frame_bytes, base + size_t(indices[k]) * frame_bytes,
                frame_bytes);
  if (type == at::kByte) return out.to(at::kFloat).div_(255.0);
  out = out.to(at::kFloat);
  check_finite(out, file.path() + ": '" + name + "'");
  return out;
}

void check_size(const at::Tensor& t, const Scene& scene, const std::string& path) {
  if (t.size(1) != scene.height || t.size(2) != scene.width)
    fail(path + ": size " + std::to_string(t.size(2)) + "x" + std::to_string(t.size(1)) + " differs from scene '" +
         scene.name + "' (" + std::to_string(scene.width) + "x" + std::to_string(scene.height) + ")");
}

}  // namespace

FrameBatch load_frames(const Scene& scene, const std::vector<int64_t>& indices, bool want_depth, bool want_normals) {
  FLAT_CHECK(!indices.empty(), scene.json_path() + ": no frames requested");
  for (int64_t i : indices)
    FLAT_CHECK(i >= 0 && i < scene.size(), scene.json_path() + ": frame " + std::to_string(i) + " out of range [0, " +
                                               std::to_string(scene.size()) + ")");
  if (want_depth && !scene.has_depth) fail(scene.json_path() + ": scene '" + scene.name + "' has no depth");
  if (want_normals && !scene.has_normals) fail(scene.json_path() + ": scene '" + scene.name + "' has no normals");
  FrameBatch out;
  if (!scene.packed.empty()) {
    auto file = safetensors::MappedFile::open(scene.path(scene.packed));
    out.images = packed_slices(*file, "images", 3, scene, indices);
    if (want_depth) out.depth = packed_slices(*file, "depth", 1, scene, indices);
    if (want_normals) out.normals = packed_slices(*file, "normals", 3, scene, indices);
    return out;
  }
  std::vector<at::Tensor> rgb, depth, normals;
  for (int64_t i : indices) {
    const auto& f = scene.frames[size_t(i)];
    rgb.push_back(read_rgb(scene.path(f.image)));
    check_size(rgb.back(), scene, scene.path(f.image));
    if (want_depth) {
      depth.push_back(read_depth(scene.path(f.depth)));
      check_size(depth.back(), scene, scene.path(f.depth));
    }
    if (want_normals) {
      normals.push_back(read_normals(scene.path(f.normals)));
      check_size(normals.back(), scene, scene.path(f.normals));
    }
  }
  out.images = at::stack(rgb);
  if (want_depth) out.depth = at::stack(depth);
  if (want_normals) out.normals = at::stack(normals);
  return out;
}

}  // namespace flat::data
