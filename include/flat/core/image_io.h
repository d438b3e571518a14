// Image files through OpenImageIO. Built with -DFLAT_WITH_OIIO=OFF every call
// throws flat::Error saying that image IO is unavailable and that safetensors
// outputs still work.
#pragma once
#include <string>
#include <vector>

#include <ATen/ATen.h>

namespace flat {

bool image_io_available();

// (C,H,W) float32 in [0,1] for 8/16-bit formats; EXR/HDR keep their values.
at::Tensor read_image(const std::string& path);
// (C,H,W) float32. PNG/JPEG: clamped to [0,1] and quantised to 8 bit (16 bit
// for PNG when `png16`); EXR: float32. Atomic (temp file, rename).
void write_image(const std::string& path, const at::Tensor& chw, bool png16 = false);
// Image files in a folder (png, jpg, jpeg, exr, tif), sorted by name.
std::vector<std::string> list_images(const std::string& folder);

// A picture for people to look at: PNG when image IO is built in, else the
// tensor as safetensors ("grid", with its layout); returns the path written.
std::string write_preview_image(const at::Tensor& chw, const std::string& path_without_extension);

}  // namespace flat
