// The cameras JSON (camera_json.h) parsed into plain numbers, without libtorch:
// every check of the format lives here, so that the fuzz target
// (fuzz/fuzz_cameras_json.cpp) exercises exactly what the tools run.
#pragma once
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

namespace flat::camera {

struct CameraRecord {
  int64_t width = 0, height = 0;
  std::array<float, 4> intrinsics{};  // fx/W, fy/H, cx/W, cy/H
  std::array<float, 16> c2w{};        // row-major 4x4, last row 0 0 0 1 (anything else is refused)
};

// One entry; throws flat::Error naming `where` and the key at fault.
CameraRecord parse_camera_record(const nlohmann::json& entry, const std::string& where);

// A whole cameras document ({"version": 1, "cameras": [...]}, one image size);
// `label` (the file) starts every error message.
std::vector<CameraRecord> parse_cameras_document(const std::string& text, const std::string& label);

}  // namespace flat::camera
