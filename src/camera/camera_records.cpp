// Torch-free parsing of cameras JSON (include/flat/camera/camera_records.h).
#include "flat/camera/camera_records.h"

#include <cmath>

#include <nlohmann/json.hpp>

#include "flat/core/error.h"

namespace flat::camera {

using nlohmann::json;

namespace {
float number(const json& v, const std::string& where, const char* key) {
  if (!v.is_number()) fail(where + ": '" + key + "' must hold numbers, got " + v.dump());
  const double x = v.get<double>();
  // Stored as float32: a finite double beyond float range is as unusable as Inf.
  if (!std::isfinite(x) || !std::isfinite(float(x))) fail(where + ": '" + key + "' holds a non-finite value");
  return float(x);
}
}  // namespace

CameraRecord parse_camera_record(const json& e, const std::string& where) {
  if (!e.is_object()) fail(where + ": a camera entry must be an object");
  for (const char* key : {"width", "height", "intrinsics", "c2w"})
    if (!e.contains(key)) fail(where + ": missing key '" + key + "'");
  if (!e["width"].is_number_integer() || !e["height"].is_number_integer() || e["width"].get<int64_t>() <= 0 ||
      e["height"].get<int64_t>() <= 0)
    fail(where + ": 'width' and 'height' must be positive integers");
  CameraRecord r;
  r.width = e["width"].get<int64_t>();
  r.height = e["height"].get<int64_t>();
  const json& k = e["intrinsics"];
  if (!k.is_array() || k.size() != 4) fail(where + ": 'intrinsics' must be [fx/W, fy/H, cx/W, cy/H]");
  for (size_t i = 0; i < 4; ++i) r.intrinsics[i] = number(k[i], where, "intrinsics");
  if (r.intrinsics[0] <= 0 || r.intrinsics[1] <= 0) fail(where + ": focal lengths in 'intrinsics' must be positive");
  const json& m = e["c2w"];
  // The whole 4x4 (docs/formats.md): a 3x4 or a last row other than 0 0 0 1
  // is not a rigid pose, and rendering it as one would be silently wrong.
  if (!m.is_array() || m.size() != 4)
    fail(where + ": 'c2w' must be a 4x4 matrix (4 rows of 4 numbers, the last 0 0 0 1), got " +
         (m.is_array() ? std::to_string(m.size()) + " rows" : m.dump()));
  for (size_t row = 0; row < 4; ++row) {
    if (!m[row].is_array() || m[row].size() != 4) fail(where + ": 'c2w' rows must have 4 numbers");
    for (size_t c = 0; c < 4; ++c) r.c2w[4 * row + c] = number(m[row][c], where, "c2w");
  }
  for (int c = 0; c < 4; ++c) {
    if (!(std::abs(r.c2w[12 + c] - (c == 3 ? 1.f : 0.f)) <= 1e-6f))
      fail(where + ": 'c2w' last row must be [0, 0, 0, 1], got " + m[3].dump());
    r.c2w[12 + c] = c == 3 ? 1.f : 0.f;
  }
  // The rotation block must be orthonormal (a rigid camera pose).
  double err = 0;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      double dot = 0;
      for (int c = 0; c < 3; ++c) dot += double(r.c2w[4 * i + c]) * double(r.c2w[4 * j + c]);
      err = std::max(err, std::abs(dot - (i == j ? 1.0 : 0.0)));
    }
  if (!(err <= 1e-3))
    fail(where + ": 'c2w' rotation is not orthonormal (max |R R^T - I| = " + std::to_string(err) + ")");
  return r;
}

std::vector<CameraRecord> parse_cameras_document(const std::string& text, const std::string& label) {
  json doc;
  try {
    doc = json::parse(text);
  } catch (const json::exception& e) {
    fail(label + ": invalid JSON: " + e.what());
  }
  if (!doc.is_object() || !doc.contains("cameras") || !doc["cameras"].is_array())
    fail(label + ": expected an object with a 'cameras' array");
  if (doc.contains("version") && doc["version"] != 1)
    fail(label + ": unsupported cameras file version " + doc["version"].dump() + " (this build reads version 1)");
  const auto& list = doc["cameras"];
  if (list.empty()) fail(label + ": 'cameras' is empty");
  std::vector<CameraRecord> out;
  for (size_t i = 0; i < list.size(); ++i) {
    const std::string where = label + ": cameras[" + std::to_string(i) + "]";
    CameraRecord r = parse_camera_record(list[i], where);
    if (i > 0 && (r.width != out[0].width || r.height != out[0].height))
      fail(where + ": size " + std::to_string(r.width) + "x" + std::to_string(r.height) + " differs from cameras[0] (" +
           std::to_string(out[0].width) + "x" + std::to_string(out[0].height) + "); one file holds one resolution");
    out.push_back(r);
  }
  return out;
}

}  // namespace flat::camera
