// Image files through OpenImageIO (PNG for colour, EXR for depth/normals).
// Without OpenImageIO (-DFLAT_WITH_OIIO=OFF) PNG and JPEG go through
// libpng/libjpeg (png_jpeg_io.cpp) and every other format throws a clear
// flat::Error naming the file; listing a folder needs only std::filesystem and
// always works. See image_io.h for what image_io_available() and
// float_image_io_available() mean.
#include "flat/core/image_io.h"

#include <algorithm>
#include <cctype>
#include <filesystem>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "flat/core/png_jpeg_io.h"
#include "flat/core/tensor_io.h"
#include "flat/core/shape.h"

#if FLAT_WITH_OIIO
#include <OpenImageIO/imageio.h>
#endif

namespace flat {
namespace {

namespace fs = std::filesystem;

// ".PNG" -> "png"
std::string lower_extension(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  if (!ext.empty() && ext[0] == '.') ext.erase(0, 1);
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  return ext;
}

#if !FLAT_WITH_OIIO
[[noreturn]] void unavailable(const std::string& path, const std::string& ext) {
  if (png_jpeg_available()) {
    fail(path + ": cannot read or write '." + ext + "' images: this build has no OpenImageIO (-DFLAT_WITH_OIIO=OFF), "
         "which every format but PNG and JPEG needs (EXR, TIFF); store depth and normals as .safetensors or .npy "
         "instead");
  }
  fail("image IO unavailable: this build has no OpenImageIO (-DFLAT_WITH_OIIO=OFF) and no libpng/libjpeg "
       "(Debian libpng-dev, libjpeg62-turbo-dev); write safetensors instead (" + path + ")");
}

bool is_png(const std::string& ext) { return ext == "png"; }
bool is_jpeg(const std::string& ext) { return ext == "jpg" || ext == "jpeg"; }
#endif

}  // namespace

bool image_io_available() { return FLAT_WITH_OIIO != 0 || png_jpeg_available(); }

bool float_image_io_available() { return FLAT_WITH_OIIO != 0; }

#if FLAT_WITH_OIIO

at::Tensor read_image(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) fail(path + ": no such image file");
  if (fs::is_directory(path, ec)) fail(path + ": is a directory, expected an image file");
  auto in = OIIO::ImageInput::open(path);
  if (!in) fail(path + ": cannot read image: " + OIIO::geterror());
  const OIIO::ImageSpec& spec = in->spec();
  if (spec.deep || spec.depth > 1) fail(path + ": deep and volume images are not supported");
  if (spec.width <= 0 || spec.height <= 0 || spec.nchannels <= 0) {
    fail(path + ": image has no pixels (" + std::to_string(spec.width) + "x" + std::to_string(spec.height) + ")");
  }
  // OpenImageIO converts to float: 8/16-bit integers are normalised to [0,1].
  auto hwc = at::empty({spec.height, spec.width, spec.nchannels}, at::kFloat);
  if (!in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, hwc.data_ptr<float>())) {
    fail(path + ": cannot read image pixels: " + in->geterror());
  }
  in->close();
  return hwc.permute({2, 0, 1}).contiguous();
}

void write_image(const std::string& path, const at::Tensor& chw, bool png16) {
  FLAT_CHECK(chw.defined() && chw.dim() == 3 && chw.size(0) >= 1 && chw.size(0) <= 4,
             path + ": write_image expects a (C,H,W) tensor with 1 to 4 channels, got " + shape_str(chw));
  FLAT_CHECK(chw.size(1) > 0 && chw.size(2) > 0, path + ": cannot write an empty image " + shape_str(chw));
  const std::string ext = lower_extension(path);
  OIIO::TypeDesc format;
  auto hwc = chw.detach().to(at::kCPU, at::kFloat).permute({1, 2, 0}).contiguous();
  if (ext == "png" || ext == "jpg" || ext == "jpeg") {
    // Integer formats: clamp to [0,1] (NaN -> 0); OpenImageIO rounds to the nearest code.
    hwc = at::nan_to_num(hwc, 0.0, 1.0, 0.0).clamp(0.0, 1.0).contiguous();
    format = (png16 && ext == "png") ? OIIO::TypeDesc::UINT16 : OIIO::TypeDesc::UINT8;
  } else if (ext == "exr" || ext == "tif" || ext == "tiff") {
    format = OIIO::TypeDesc::FLOAT;  // keeps the values (depth, normals) exactly
  } else {
    fail(path + ": unsupported image extension '" + ext + "' (use png, jpg, exr or tif)");
  }

  // The temp file ends in the real extension: OpenImageIO picks the format from it.
  AtomicFile file(path, "." + ext);
  auto out = OIIO::ImageOutput::create(file.temp_path());
  if (!out) fail(path + ": no image writer for '." + ext + "': " + OIIO::geterror());
  OIIO::ImageSpec spec(static_cast<int>(hwc.size(1)), static_cast<int>(hwc.size(0)), static_cast<int>(hwc.size(2)),
                       format);
  if (!out->open(file.temp_path(), spec)) fail(path + ": cannot write image: " + out->geterror());
  if (!out->write_image(OIIO::TypeDesc::FLOAT, hwc.data_ptr<float>())) {
    fail(path + ": cannot write image pixels: " + out->geterror());
  }
  if (!out->close()) fail(path + ": cannot finish image: " + out->geterror());
  out.reset();
  file.commit();
}

#else

// PNG and JPEG through libpng/libjpeg; the rest needs OpenImageIO.
at::Tensor read_image(const std::string& path) {
  const std::string ext = lower_extension(path);
  if (png_jpeg_available() && is_png(ext)) return read_png(path);
  if (png_jpeg_available() && is_jpeg(ext)) return read_jpeg(path);
  unavailable(path, ext);
}

void write_image(const std::string& path, const at::Tensor& chw, bool png16) {
  const std::string ext = lower_extension(path);
  if (png_jpeg_available() && is_png(ext)) return write_png(path, chw, png16);
  if (png_jpeg_available() && is_jpeg(ext)) return write_jpeg(path, chw);
  if (png_jpeg_available() && ext != "exr" && ext != "tif" && ext != "tiff") {
    fail(path + ": unsupported image extension '" + ext + "' (use png, jpg, exr or tif)");
  }
  unavailable(path, ext);
}

#endif

std::vector<std::string> list_images(const std::string& folder) {
  std::error_code ec;
  if (!fs::is_directory(folder, ec)) fail(folder + ": not a folder (looking for images)");
  static const char* const kExtensions[] = {"png", "jpg", "jpeg", "exr", "tif", "tiff"};
  std::vector<std::string> images;
  for (const auto& item : fs::directory_iterator(folder, ec)) {
    if (!item.is_regular_file()) continue;
    const std::string ext = lower_extension(item.path().string());
    if (std::find(std::begin(kExtensions), std::end(kExtensions), ext) != std::end(kExtensions)) {
      images.push_back(item.path().string());
    }
  }
  if (ec) fail(folder + ": cannot list folder: " + ec.message());
  std::sort(images.begin(), images.end());  // same folder, so this sorts by file name
  return images;
}

std::string write_preview_image(const at::Tensor& chw, const std::string& path_without_extension) {
  if (image_io_available()) {
    const std::string path = path_without_extension + ".png";
    write_image(path, chw);
    return path;
  }
  const std::string path = path_without_extension + ".safetensors";
  save_safetensors(path, {{"grid", chw.contiguous()}}, {{"layout", "(3,H,W) in [0,1]"}});
  return path;
}

}  // namespace flat
