// Cameras as JSON, the scene format's camera entries (docs/formats.md):
//   {"version": 1, "cameras": [ {"width": 768, "height": 432,
//     "intrinsics": [fx/W, fy/H, cx/W, cy/H],
//     "c2w": [[r00,r01,r02,tx],[r10,r11,r12,ty],[r20,r21,r22,tz],[0,0,0,1]]}, ... ]}
// OpenCV axes (x right, y down, z forward), metres. All cameras of one file
// share one image size (the rasterizer renders V views at one resolution).
#pragma once
#include <string>

#include <nlohmann/json_fwd.hpp>

#include "flat/camera/cameras.h"

namespace flat::camera {

struct CameraSet {
  Cameras cameras;  // float32, CPU
  int64_t width = 0;
  int64_t height = 0;
};

// One entry -> (intrinsics (4,), c2w (4,4)); `where` names it in errors
// ("cams.json: cameras[3]: 'c2w' must be 4x4 numbers").
void parse_camera_entry(const nlohmann::json& entry, const std::string& where, at::Tensor& intrinsics,
                        at::Tensor& c2w, int64_t& width, int64_t& height);
nlohmann::json camera_entry(const at::Tensor& intrinsics, const at::Tensor& c2w, int64_t width, int64_t height);

CameraSet read_cameras_json(const std::string& path);
void write_cameras_json(const std::string& path, const CameraSet& set);  // atomic

}  // namespace flat::camera
