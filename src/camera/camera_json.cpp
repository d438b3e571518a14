#include "flat/camera/camera_json.h"

#include <cstring>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>

#include "flat/camera/camera_records.h"
#include "flat/core/atomic_file.h"
#include "flat/core/error.h"

namespace flat::camera {

using nlohmann::json;

void parse_camera_entry(const json& e, const std::string& where, at::Tensor& intrinsics, at::Tensor& c2w,
                        int64_t& width, int64_t& height) {
  CameraRecord r = parse_camera_record(e, where);
  width = r.width;
  height = r.height;
  intrinsics = at::tensor(at::ArrayRef<float>(r.intrinsics.data(), 4), at::kFloat);
  c2w = at::tensor(at::ArrayRef<float>(r.c2w.data(), 16), at::kFloat).view({4, 4});
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
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path + ": cannot open cameras file");
  std::stringstream text;
  text << in.rdbuf();
  const auto records = parse_cameras_document(text.str(), path);
  CameraSet set;
  set.width = records.front().width;
  set.height = records.front().height;
  const int64_t n = int64_t(records.size());
  set.cameras.intrinsics = at::empty({n, 4}, at::kFloat);
  set.cameras.c2w = at::empty({n, 4, 4}, at::kFloat);
  for (int64_t i = 0; i < n; ++i) {
    std::memcpy(set.cameras.intrinsics[i].data_ptr<float>(), records[size_t(i)].intrinsics.data(), 4 * sizeof(float));
    std::memcpy(set.cameras.c2w[i].data_ptr<float>(), records[size_t(i)].c2w.data(), 16 * sizeof(float));
  }
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
