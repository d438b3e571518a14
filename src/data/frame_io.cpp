#include "flat/data/frame_io.h"

#include <algorithm>
#include <cctype>
#include <filesystem>

#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/shape.h"
#include "flat/core/tensor_io.h"

namespace flat::data {

namespace {

std::string extension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

bool is_safetensors(const std::string& path) { return extension(path) == ".safetensors"; }

at::Tensor read_one(const std::string& path, const char* name) {
  if (!std::filesystem::exists(path)) fail(path + ": file does not exist");
  if (is_safetensors(path)) {
    auto map = load_safetensors(path);
    auto it = map.find(name);
    if (it == map.end()) fail(path + ": no tensor named '" + name + "'");
    return it->second;
  }
  return read_image(path);
}

void write_one(const std::string& path, const at::Tensor& t, const char* name) {
  if (is_safetensors(path)) {
    save_safetensors(path, {{name, t.contiguous()}});
    return;
  }
  write_image(path, t);
}

}  // namespace

at::Tensor read_rgb(const std::string& path) {
  at::Tensor t = read_one(path, "image");
  if (t.dim() == 3 && t.size(0) == 4) t = t.narrow(0, 0, 3);       // drop alpha
  if (t.dim() == 3 && t.size(0) == 1) t = t.expand({3, -1, -1});   // grey
  check_shape(t, {3, -1, -1}, path + ": image", "(3,H,W)");
  if (t.scalar_type() == at::kByte) t = t.to(at::kFloat) / 255.0;
  t = t.to(at::kFloat).contiguous();
  check_finite(t, path + ": image");
  return t;
}

at::Tensor read_depth(const std::string& path) {
  at::Tensor t = read_one(path, "depth");
  if (t.dim() == 2) t = t.unsqueeze(0);
  if (t.dim() == 3 && t.size(0) > 1 && !is_safetensors(path)) t = t.narrow(0, 0, 1);  // EXR written as RGB/Y
  check_shape(t, {1, -1, -1}, path + ": depth", "(1,H,W)");
  t = t.to(at::kFloat).contiguous();
  check_finite(t, path + ": depth");
  FLAT_CHECK(t.min().item<float>() >= 0, path + ": depth has negative values (0 marks invalid pixels)");
  return t;
}

at::Tensor read_normals(const std::string& path) {
  at::Tensor t = read_one(path, "normals");
  if (t.dim() == 3 && t.size(0) == 4) t = t.narrow(0, 0, 3);
  check_shape(t, {3, -1, -1}, path + ": normals", "(3,H,W)");
  t = t.to(at::kFloat).contiguous();
  check_finite(t, path + ": normals");
  return t;
}

void write_rgb(const std::string& path, const at::Tensor& rgb) {
  check_shape(rgb, {3, -1, -1}, path + ": image", "(3,H,W)");
  if (is_safetensors(path)) {
    write_one(path, (rgb.clamp(0, 1) * 255).round().to(at::kByte).cpu(), "image");
    return;
  }
  write_one(path, rgb.to(at::kFloat).cpu(), "image");
}

void write_depth(const std::string& path, const at::Tensor& depth) {
  check_shape(depth, {1, -1, -1}, path + ": depth", "(1,H,W)");
  write_one(path, depth.to(at::kFloat).cpu(), "depth");
}

void write_normals(const std::string& path, const at::Tensor& normals) {
  check_shape(normals, {3, -1, -1}, path + ": normals", "(3,H,W)");
  write_one(path, normals.to(at::kFloat).cpu(), "normals");
}

std::string float_map_extension() { return float_image_io_available() ? ".exr" : ".safetensors"; }
std::string rgb_extension() { return image_io_available() ? ".png" : ".safetensors"; }

}  // namespace flat::data
