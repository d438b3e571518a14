#include "flat/camera/camera_json.h"

#include <fstream>

#include <nlohmann/json.hpp>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"

namespace flat::camera {

using nlohmann::json;

namespace {
double number(const json& v, const std::string& where, const char* key) {
  if (!v.is_number()) fail(where + ": '" + key + "' must hold numbers, got " + v.dump());
  double x = v.get<double>();
  if (!std::isfinite(x)) fail(where + ": '" + key + "' holds a non-finite value");
  return x;
}
}  // namespace

void parse_camera_entry(const json& e, const std::string& where, at::Tensor& intrinsics, at::Tensor& c2w,
                        int64_t& width, int64_t& height) {
  if (!e.is_object()) fail(where + ": a camera entry must be an object");
  for (const char* key : {"width", "height", "intrinsics", "c2w"})
    if (!e.contains(key)) fail(where + ": missing key '" + key + "'");
  if (!e["width"].is_number_integer() || !e["height"].is_number_integer() || e["width"].get<int64_t>() <= 0 ||
      e["height"].get<int64_t>() <= 0)
    fail(where + ": 'width' and 'height' must be positive integers");
  width = e["width"].get<int64_t>();
  height = e["height"].get<int64_t>();
  const json& k = e["intrinsics"];
  if (!k.is_array() || k.size() != 4) fail(where + ": 'intrinsics' must be [fx/W, fy/H, cx/W, cy/H]");
  intrinsics = at::empty({4}, at::kFloat);
  for (int i = 0; i < 4; ++i) intrinsics[i] = number(k[i], where, "intrinsics");
  if (intrinsics[0].item<float>() <= 0 || intrinsics[1].item<float>() <= 0)
    fail(where + ": focal lengths in 'intrinsics' must be positive");
  const json& m = e["c2w"];
  if (!m.is_array() || (m.size() != 4 && m.size() != 3)) fail(where + ": 'c2w' must be a 4x4 (or 3x4) matrix");
  c2w = at::eye(4, at::kFloat);
  for (size_t r = 0; r < m.size(); ++r) {
    if (!m[r].is_array() || m[r].size() != 4) fail(where + ": 'c2w' rows must have 4 numbers");
    for (int c = 0; c < 4; ++c) c2w[r][c] = number(m[r][c], where, "c2w");
  }
  // The rotation block must be orthonormal (a rigid camera pose).
  auto R = c2w.narrow(0, 0, 3).narrow(1, 0, 3).to(at::kDouble);
  double err = (at::matmul(R, R.t()) - at::eye(3, at::kDouble)).abs().max().item<double>();
  if (err > 1e-3) fail(where + ": 'c2w' rotation is not orthonormal (max |R R^T - I| = " + std::to_string(err) + ")");
}

json camera_entry(const at::Tensor& intrinsics, const at::Tensor& c2w, int64_t width, int64_t height) {
  auto k = intrinsics.to(at::kDouble).cpu().contiguous();
  auto m = c2w.to(at::kDouble).cpu().contiguous();
  json e;
  e["width"] = width;
  e["height"] = height;
  e["intrinsics"] = {k[0].item<double>(), k[1].item<double>(), k[2].item<double>(), k[3].item<double>()};
  json rows = json::array();
  for (int r = 0; r < 4; ++r) {
    json row = json::array();
    for (int c = 0; c < 4; ++c) row.push_back(m[r][c].item<double>());
    rows.push_back(row);
  }
  e["c2w"] = rows;
  return e;
}

CameraSet read_cameras_json(const std::string& path) {
  std::ifstream in(path);
  if (!in) fail(path + ": cannot open cameras file");
  json doc;
  try {
    doc = json::parse(in);
  } catch (const json::exception& e) {
    fail(path + ": invalid JSON: " + e.what());
  }
  if (!doc.is_object() || !doc.contains("cameras") || !doc["cameras"].is_array())
    fail(path + ": expected an object with a 'cameras' array");
  if (doc.contains("version") && doc["version"] != 1)
    fail(path + ": unsupported cameras file version " + doc["version"].dump() + " (this build reads version 1)");
  const auto& list = doc["cameras"];
  if (list.empty()) fail(path + ": 'cameras' is empty");
  CameraSet set;
  std::vector<at::Tensor> ks, ms;
  for (size_t i = 0; i < list.size(); ++i) {
    at::Tensor k, m;
    int64_t w = 0, h = 0;
    std::string where = path + ": cameras[" + std::to_string(i) + "]";
    parse_camera_entry(list[i], where, k, m, w, h);
    if (i == 0) {
      set.width = w;
      set.height = h;
    } else if (w != set.width || h != set.height) {
      fail(where + ": size " + std::to_string(w) + "x" + std::to_string(h) + " differs from cameras[0] (" +
           std::to_string(set.width) + "x" + std::to_string(set.height) + "); one file holds one resolution");
    }
    ks.push_back(k);
    ms.push_back(m);
  }
  set.cameras = {at::stack(ks), at::stack(ms)};
  return set;
}

void write_cameras_json(const std::string& path, const CameraSet& set) {
  json doc;
  doc["version"] = 1;
  doc["cameras"] = json::array();
  for (int64_t i = 0; i < set.cameras.size(); ++i)
    doc["cameras"].push_back(camera_entry(set.cameras.intrinsics[i], set.cameras.c2w[i], set.width, set.height));
  write_file_atomic(path, doc.dump(2) + "\n");
}

}  // namespace flat::camera
