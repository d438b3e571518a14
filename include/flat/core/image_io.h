// Image files. With OpenImageIO (the default) every format goes through it:
// PNG/JPEG for colour, EXR/TIFF for float maps (depth, normals). Built with
// -DFLAT_WITH_OIIO=OFF, PNG and JPEG go through libpng/libjpeg instead
// (core/png_jpeg_io.h, same numbers) when CMake found them, and EXR/TIFF
// throw a flat::Error naming the file (depth and normals then go to
// .safetensors or .npy).
//
// Two questions, two functions, for the tools that pick an output format:
// * image_io_available(): PNG and JPEG can be read and written (OpenImageIO or
//   libpng/libjpeg). Decides PNG vs safetensors for colour images, previews,
//   and whether a photo capture can be imported. False only in a build with
//   neither (every read/write then throws, naming the path).
// * float_image_io_available(): EXR (and TIFF) can be read and written, i.e.
//   OpenImageIO is built in. Decides EXR vs safetensors for depth/normals.
#pragma once
#include <string>
#include <vector>

#include <ATen/ATen.h>

namespace flat {

bool image_io_available();
bool float_image_io_available();

// (C,H,W) float32 in [0,1] for 8/16-bit formats; EXR/HDR keep their values.
at::Tensor read_image(const std::string& path);
// (C,H,W) float32. PNG/JPEG: clamped to [0,1] and quantised to 8 bit (16 bit
// for PNG when `png16`); EXR: float32. Atomic (temp file, rename).
void write_image(const std::string& path, const at::Tensor& chw, bool png16 = false);
// Image files in a folder (png, jpg, jpeg, exr, tif), sorted by name.
std::vector<std::string> list_images(const std::string& folder);

// A picture for people to look at: PNG when image_io_available(), else the
// tensor as safetensors ("grid", with its layout); returns the path written.
std::string write_preview_image(const at::Tensor& chw, const std::string& path_without_extension);

}  // namespace flat
