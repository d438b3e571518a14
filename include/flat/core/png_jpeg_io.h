// PNG and JPEG files through libpng and libjpeg(-turbo), for builds without
// OpenImageIO (-DFLAT_WITH_OIIO=OFF, the GPU machine's). read_image and
// write_image (image_io.h) dispatch .png/.jpg/.jpeg here when OpenImageIO is
// off; EXR and TIFF still need OpenImageIO.
//
// Same numbers as the OpenImageIO path (OpenImageIO 2.4, checked by
// tests/core/test_png_jpeg_io.cpp in the build that has both):
// * read: (C,H,W) float32, C = the file's channels after expanding palettes,
//   low bit depths and tRNS transparency (1 gray, 2 gray+alpha, 3 RGB,
//   4 RGBA); 8-bit codes times 1/255, 16-bit codes times 1/65535. Colour of
//   an image with alpha comes back multiplied by alpha (associated), in
//   integer arithmetic before the conversion to float, as OpenImageIO does
//   (with its gAMA-chunk variant: colour times (alpha)^gamma). JPEG: 8-bit
//   gray (C=1) or RGB (C=3); CMYK JPEGs are refused.
// * write: values outside [0,1] are clamped, NaN written as 0, rounded to the
//   nearest code. PNG with alpha (C = 2 or 4) divides colour by alpha before
//   writing (PNG stores unassociated alpha). JPEG: C=1 gray, C=3 RGB, C=4
//   writes RGB and drops alpha (as OpenImageIO does), C=2 is refused; quality
//   kJpegQuality (OpenImageIO's default) unless given. Writes are atomic
//   (temp file beside the target, then rename; core/atomic_file.h).
// * errors: flat::Error naming the file (missing, not a PNG/JPEG, truncated
//   or corrupt data, unsupported layout); a corrupt file never aborts the
//   process (libpng's and libjpeg's error exits longjmp back and throw).
//   A JPEG cut short is an error, not an image padded with grey.
//
// Built only when CMake finds libpng and libjpeg (Debian libpng-dev,
// libjpeg62-turbo-dev), with FLAT_WITH_PNG_JPEG=1 in the core module; without
// them png_jpeg_available() is false and every call throws a flat::Error.
#pragma once
#include <string>

#include <ATen/ATen.h>

namespace flat {

// Whether this build has libpng and libjpeg (independent of OpenImageIO).
bool png_jpeg_available();

inline constexpr int kJpegQuality = 98;

at::Tensor read_png(const std::string& path);
at::Tensor read_jpeg(const std::string& path);
// (C,H,W), C in 1..4; 16-bit codes when `sixteen_bit`, else 8-bit.
void write_png(const std::string& path, const at::Tensor& chw, bool sixteen_bit = false);
// (C,H,W), C = 1, 3 or 4 (alpha dropped); quality 1..100.
void write_jpeg(const std::string& path, const at::Tensor& chw, int quality = kJpegQuality);

}  // namespace flat
