// Frame files of a scene, chosen by extension:
//   .png/.jpg/.jpeg  RGB through OpenImageIO (8-bit)
//   .exr             float depth (1 channel) or normals (3 channels) through OpenImageIO
//   .safetensors     one tensor named "image" (U8 or F32, (3,H,W)), "depth" (F32, (1,H,W))
//                    or "normals" (F32/F16, (3,H,W)); works without OpenImageIO
// Readers check shape and finiteness and name the file in every error.
#pragma once
#include <string>

#include <ATen/ATen.h>

namespace flat::data {

at::Tensor read_rgb(const std::string& path);      // (3,H,W) float32 in [0,1]
at::Tensor read_depth(const std::string& path);    // (1,H,W) float32, >= 0 (0 = invalid)
at::Tensor read_normals(const std::string& path);  // (3,H,W) float32

void write_rgb(const std::string& path, const at::Tensor& rgb);          // (3,H,W) in [0,1]
void write_depth(const std::string& path, const at::Tensor& depth);      // (1,H,W)
void write_normals(const std::string& path, const at::Tensor& normals);  // (3,H,W)

// The extension a tool should use for depth/normals: ".exr" with OpenImageIO,
// else ".safetensors"; for RGB ".png" or ".safetensors".
std::string float_map_extension();
std::string rgb_extension();

}  // namespace flat::data
