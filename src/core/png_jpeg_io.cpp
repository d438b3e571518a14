// PNG through libpng's classic API, JPEG through libjpeg(-turbo): see
// png_jpeg_io.h for what is read and written. Files are read whole into
// memory and decoded from there, and encoded into the temp file of an
// AtomicFile. libpng and libjpeg report fatal errors by calling an error
// function that must not return: ours record the message and longjmp back to
// the decode/encode function, which then throws flat::Error naming the file.
// Between setjmp and a possible longjmp no C++ object with a destructor is
// created in that function: everything it owns is declared before setjmp.
#include "flat/core/png_jpeg_io.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <csetjmp>
#include <filesystem>
#include <fstream>
#include <vector>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "flat/core/shape.h"

#if FLAT_WITH_PNG_JPEG
#include <png.h>
// jpeglib.h needs FILE and size_t declared before it.
#include <jpeglib.h>
#include <jerror.h>
#endif

namespace flat {
namespace {

namespace fs = std::filesystem;

#if FLAT_WITH_PNG_JPEG

// Larger decoded images are refused before any allocation (a corrupt or
// hostile header can claim 2^31 x 2^31 pixels): 2^32 bytes is a 32k x 32k
// 16-bit RGBA image.
constexpr uint64_t kMaxDecodedBytes = uint64_t(1) << 32;

std::vector<unsigned char> read_whole_file(const std::string& path, const char* kind) {
  std::error_code ec;
  if (!fs::exists(path, ec)) fail(path + ": no such image file");
  if (fs::is_directory(path, ec)) fail(path + ": is a directory, expected an image file");
  const auto size = fs::file_size(path, ec);
  if (ec) fail(path + ": cannot read " + kind + " file: " + ec.message());
  if (size == 0) fail(path + ": empty file, expected a " + std::string(kind) + " image");
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path + ": cannot open " + kind + " file: " + std::strerror(errno));
  std::vector<unsigned char> bytes(static_cast<size_t>(size));
  in.read(reinterpret_cast<char*>(bytes.data()), std::streamsize(size));
  if (in.gcount() != std::streamsize(size)) fail(path + ": cannot read " + kind + " file (changed while reading?)");
  return bytes;
}

// (C,H,W) of 8- or 16-bit codes, interleaved, -> (C,H,W) float32 as
// OpenImageIO converts integers: code times the reciprocal of the maximum.
at::Tensor codes_to_chw(const std::vector<uint16_t>& codes, int64_t height, int64_t width, int64_t channels,
                        int bit_depth) {
  const float scale = bit_depth == 16 ? 1.0f / 65535.0f : 1.0f / 255.0f;
  auto hwc = at::empty({height, width, channels}, at::kFloat);
  float* out = hwc.data_ptr<float>();
  for (size_t i = 0; i < codes.size(); ++i) out[i] = float(codes[i]) * scale;
  return hwc.permute({2, 0, 1}).contiguous();
}

// (C,H,W) float -> (H,W,C) codes, clamped to [0,1] (NaN -> 0) and rounded to
// the nearest code as OpenImageIO does (v * max + 0.5, truncated).
std::vector<uint16_t> chw_to_codes(const at::Tensor& chw, int bit_depth) {
  auto hwc = at::nan_to_num(chw.detach().to(at::kCPU, at::kFloat), 0.0, 1.0, 0.0)
                 .clamp(0.0, 1.0)
                 .permute({1, 2, 0})
                 .contiguous();
  const float max = bit_depth == 16 ? 65535.0f : 255.0f;
  const float* in = hwc.data_ptr<float>();
  std::vector<uint16_t> codes(size_t(hwc.numel()));
  for (size_t i = 0; i < codes.size(); ++i) codes[i] = uint16_t(in[i] * max + 0.5f);
  return codes;
}

void check_chw(const std::string& path, const at::Tensor& chw, const char* allowed, bool ok_channels) {
  FLAT_CHECK(chw.defined() && chw.dim() == 3 && ok_channels,
             path + ": write_image expects a (C,H,W) tensor with " + allowed + " channels, got " + shape_str(chw));
  FLAT_CHECK(chw.size(1) > 0 && chw.size(2) > 0, path + ": cannot write an empty image " + shape_str(chw));
  FLAT_CHECK(chw.size(1) <= 0x7fffffff && chw.size(2) <= 0x7fffffff, path + ": image too large " + shape_str(chw));
}

// ---------------------------------------------------------------- PNG

struct PngFailure {
  std::jmp_buf jump;
  char message[256] = {0};
};

void png_error_fn(png_structp png, png_const_charp message) {
  auto* failure = static_cast<PngFailure*>(png_get_error_ptr(png));
  std::snprintf(failure->message, sizeof(failure->message), "%s", message ? message : "libpng error");
  std::longjmp(failure->jump, 1);
}

void png_warning_fn(png_structp, png_const_charp) {}  // benign (unknown chunks, bad CRC in ancillary data)

struct PngSource {
  const unsigned char* data;
  size_t size, offset;
};

void png_read_fn(png_structp png, png_bytep out, png_size_t length) {
  auto* src = static_cast<PngSource*>(png_get_io_ptr(png));
  if (length > src->size - src->offset) png_error(png, "truncated file (data ends early)");
  std::memcpy(out, src->data + src->offset, length);
  src->offset += length;
}

struct PngReadGuard {
  png_structp png = nullptr;
  png_infop info = nullptr;
  ~PngReadGuard() { png_destroy_read_struct(&png, info ? &info : nullptr, nullptr); }
};

// The info struct beside a libpng reader or writer (`what`) just created;
// false with `error` set when either could not be made. Called before
// setjmp, which must stay in the function that calls libpng.
bool with_info(png_structp png, png_infop& info, const char* what, std::string& error) {
  if (!png) {
    error = std::string("cannot create a libpng ") + what + " (out of memory?)";
    return false;
  }
  info = png_create_info_struct(png);
  if (!info) {
    error = "cannot create a libpng info struct (out of memory?)";
    return false;
  }
  return true;
}

struct PngImage {
  int64_t width = 0, height = 0, channels = 0;
  int bit_depth = 8;
  float gamma = 1.0f;  // OpenImageIO's "oiio:Gamma": from gAMA unless sRGB
  std::vector<unsigned char> rows;
};

// Decodes into `out`; false with `error` set when libpng gives up.
bool decode_png(const std::vector<unsigned char>& bytes, PngImage& out, std::string& error) {
  PngFailure failure;
  PngReadGuard guard;
  PngSource source{bytes.data(), bytes.size(), 0};
  std::vector<png_bytep> row_pointers;
  guard.png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &failure, png_error_fn, png_warning_fn);
  if (!with_info(guard.png, guard.info, "reader", error)) return false;
  if (setjmp(failure.jump)) {
    error = failure.message;
    return false;
  }
  png_set_read_fn(guard.png, &source, png_read_fn);
  png_read_info(guard.png, guard.info);
  const int color_type = png_get_color_type(guard.png, guard.info);
  const int file_depth = png_get_bit_depth(guard.png, guard.info);
  // The transforms OpenImageIO applies: palettes to RGB, gray 1/2/4 bit to 8,
  // tRNS to an alpha channel. No gamma or colour conversion.
  if (color_type == PNG_COLOR_TYPE_PALETTE) png_set_palette_to_rgb(guard.png);
  if (color_type == PNG_COLOR_TYPE_GRAY && file_depth < 8) png_set_expand_gray_1_2_4_to_8(guard.png);
  if (png_get_valid(guard.png, guard.info, PNG_INFO_tRNS)) png_set_tRNS_to_alpha(guard.png);
  png_set_interlace_handling(guard.png);
  png_read_update_info(guard.png, guard.info);

  out.width = png_get_image_width(guard.png, guard.info);
  out.height = png_get_image_height(guard.png, guard.info);
  out.channels = png_get_channels(guard.png, guard.info);
  out.bit_depth = png_get_bit_depth(guard.png, guard.info);
  int srgb_intent = 0;
  double file_gamma = 0.0;
  if (!png_get_sRGB(guard.png, guard.info, &srgb_intent) && png_get_gAMA(guard.png, guard.info, &file_gamma) &&
      file_gamma > 0.0) {
    const float g = float(1.0 / file_gamma);
    out.gamma = std::round(100.0f * g) / 100.0f;
  }
  const size_t row_bytes = png_get_rowbytes(guard.png, guard.info);
  if (out.width <= 0 || out.height <= 0 || out.channels < 1 || out.channels > 4 ||
      (out.bit_depth != 8 && out.bit_depth != 16) ||
      row_bytes != size_t(out.width * out.channels * (out.bit_depth / 8))) {
    error = "unsupported PNG layout (" + std::to_string(out.channels) + " channels, " +
            std::to_string(out.bit_depth) + " bit)";
    return false;
  }
  if (uint64_t(row_bytes) * uint64_t(out.height) > kMaxDecodedBytes) {
    error = "image too large (" + std::to_string(out.width) + "x" + std::to_string(out.height) + ")";
    return false;
  }
  out.rows.resize(row_bytes * size_t(out.height));
  row_pointers.resize(size_t(out.height));
  for (int64_t y = 0; y < out.height; ++y) row_pointers[size_t(y)] = out.rows.data() + size_t(y) * row_bytes;
  png_read_image(guard.png, row_pointers.data());
  png_read_end(guard.png, nullptr);  // checks the data up to IEND (a cut file fails here too)
  return true;
}

// OpenImageIO 2.4's associateAlpha (pnginput.cpp): colour times alpha in
// integers (truncated), or times (alpha/max)^gamma when the file has a gAMA.
void associate_alpha(std::vector<uint16_t>& codes, int64_t channels, int bit_depth, float gamma) {
  const unsigned max = bit_depth == 16 ? 65535u : 255u;
  const int64_t alpha = channels - 1;
  const size_t pixels = codes.size() / size_t(channels);
  uint16_t* p = codes.data();
  if (gamma == 1.0f) {
    for (size_t i = 0; i < pixels; ++i, p += channels) {
      for (int64_t c = 0; c < alpha; ++c) p[c] = uint16_t((unsigned(p[c]) * p[alpha]) / max);
    }
  } else {
    const float inv_max = 1.0f / float(max);
    for (size_t i = 0; i < pixels; ++i, p += channels) {
      const float a = std::pow(float(p[alpha]) * inv_max, gamma);
      for (int64_t c = 0; c < alpha; ++c) p[c] = uint16_t(float(p[c]) * a);
    }
  }
}

// OpenImageIO 2.4's deassociateAlpha (pngoutput.cpp, gamma 1): colour times
// max over alpha in integers (truncated, at most max); alpha 0 leaves colour.
void deassociate_alpha(std::vector<uint16_t>& codes, int64_t channels, int bit_depth) {
  const unsigned max = bit_depth == 16 ? 65535u : 255u;
  const int64_t alpha = channels - 1;
  const size_t pixels = codes.size() / size_t(channels);
  uint16_t* p = codes.data();
  for (size_t i = 0; i < pixels; ++i, p += channels) {
    if (!p[alpha]) continue;
    for (int64_t c = 0; c < alpha; ++c) p[c] = uint16_t(std::min(max, (unsigned(p[c]) * max) / p[alpha]));
  }
}

struct PngWriteGuard {
  png_structp png = nullptr;
  png_infop info = nullptr;
  ~PngWriteGuard() { png_destroy_write_struct(&png, info ? &info : nullptr); }
};

void png_write_fn(png_structp png, png_bytep data, png_size_t length) {
  auto* out = static_cast<std::ostream*>(png_get_io_ptr(png));
  out->write(reinterpret_cast<const char*>(data), std::streamsize(length));
  if (!*out) png_error(png, "cannot write to the temp file (disk full?)");
}

void png_flush_fn(png_structp) {}  // AtomicFile::commit flushes and syncs

bool encode_png(const std::vector<unsigned char>& rows, int64_t width, int64_t height, int64_t channels,
                int bit_depth, std::ostream& stream, std::string& error) {
  static const int kColorTypes[] = {PNG_COLOR_TYPE_GRAY, PNG_COLOR_TYPE_GRAY_ALPHA, PNG_COLOR_TYPE_RGB,
                                    PNG_COLOR_TYPE_RGB_ALPHA};
  PngFailure failure;
  PngWriteGuard guard;
  const size_t row_bytes = size_t(width * channels * (bit_depth / 8));
  guard.png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &failure, png_error_fn, png_warning_fn);
  if (!with_info(guard.png, guard.info, "writer", error)) return false;
  if (setjmp(failure.jump)) {
    error = failure.message;
    return false;
  }
  png_set_write_fn(guard.png, &stream, png_write_fn, png_flush_fn);
  png_set_IHDR(guard.png, guard.info, png_uint_32(width), png_uint_32(height), bit_depth,
               kColorTypes[channels - 1], PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(guard.png, guard.info);
  for (int64_t y = 0; y < height; ++y) {
    png_write_row(guard.png, const_cast<png_bytep>(rows.data() + size_t(y) * row_bytes));
  }
  png_write_end(guard.png, nullptr);
  return true;
}

// ---------------------------------------------------------------- JPEG

struct JpegFailure {
  jpeg_error_mgr manager;  // first: libjpeg's cinfo->err points here
  std::jmp_buf jump;
  char message[JMSG_LENGTH_MAX] = {0};
};

[[noreturn]] void jpeg_error_exit_fn(j_common_ptr cinfo) {
  auto* failure = reinterpret_cast<JpegFailure*>(cinfo->err);
  (*cinfo->err->format_message)(cinfo, failure->message);
  std::longjmp(failure->jump, 1);
}

// Warnings (level -1) that mean the pixels are wrong: libjpeg would go on and
// fill what is missing with grey; a cut or damaged photo is refused instead.
void jpeg_emit_message_fn(j_common_ptr cinfo, int level) {
  if (level >= 0) return;  // trace messages
  switch (cinfo->err->msg_code) {
    case JWRN_JPEG_EOF:
    case JWRN_HIT_MARKER:
    case JWRN_HUFF_BAD_CODE:
    case JWRN_ARITH_BAD_CODE:
    case JWRN_MUST_RESYNC:
    case JWRN_BOGUS_PROGRESSION:
    case JWRN_NOT_SEQUENTIAL:
      jpeg_error_exit_fn(cinfo);
    default:
      cinfo->err->num_warnings++;  // benign (unknown JFIF revision, extraneous bytes, ...)
  }
}

void create_jpeg_struct(jpeg_decompress_struct* cinfo) { jpeg_create_decompress(cinfo); }
void create_jpeg_struct(jpeg_compress_struct* cinfo) { jpeg_create_compress(cinfo); }

// A libjpeg decompressor or compressor (Cinfo) with its error handling: its
// errors jump to failure.jump, so create() it after setjmp there; destroyed
// with the guard.
template <class Cinfo>
struct JpegGuard {
  JpegFailure failure;
  Cinfo cinfo;
  bool created = false;
  JpegGuard() {
    jpeg_std_error(&failure.manager);
    failure.manager.error_exit = jpeg_error_exit_fn;
    failure.manager.emit_message = jpeg_emit_message_fn;
    cinfo.err = &failure.manager;
  }
  void create() {
    create_jpeg_struct(&cinfo);
    created = true;
  }
  ~JpegGuard() {
    if (created) jpeg_destroy(reinterpret_cast<j_common_ptr>(&cinfo));
  }
};

struct JpegImage {
  int64_t width = 0, height = 0, channels = 0;
  std::vector<unsigned char> pixels;
};

bool decode_jpeg(const std::vector<unsigned char>& bytes, JpegImage& out, std::string& error) {
  JpegGuard<jpeg_decompress_struct> guard;
  JpegFailure& failure = guard.failure;
  if (setjmp(failure.jump)) {
    error = failure.message;
    return false;
  }
  guard.create();
  jpeg_mem_src(&guard.cinfo, bytes.data(), static_cast<unsigned long>(bytes.size()));
  jpeg_read_header(&guard.cinfo, TRUE);
  switch (guard.cinfo.jpeg_color_space) {
    case JCS_GRAYSCALE:
      guard.cinfo.out_color_space = JCS_GRAYSCALE;
      break;
    case JCS_YCbCr:
    case JCS_RGB:
      guard.cinfo.out_color_space = JCS_RGB;
      break;
    default:
      std::snprintf(failure.message, sizeof(failure.message),
                    "unsupported JPEG colour space (CMYK/YCCK or unknown, libjpeg code %d): convert it to RGB",
                    int(guard.cinfo.jpeg_color_space));
      std::longjmp(failure.jump, 1);
  }
  jpeg_start_decompress(&guard.cinfo);
  out.width = guard.cinfo.output_width;
  out.height = guard.cinfo.output_height;
  out.channels = guard.cinfo.output_components;
  const uint64_t row_bytes = uint64_t(out.width) * uint64_t(out.channels);
  if (row_bytes * uint64_t(out.height) > kMaxDecodedBytes) {
    std::snprintf(failure.message, sizeof(failure.message), "image too large (%lldx%lld)", (long long)out.width,
                  (long long)out.height);
    std::longjmp(failure.jump, 1);
  }
  out.pixels.resize(size_t(row_bytes * uint64_t(out.height)));
  while (guard.cinfo.output_scanline < guard.cinfo.output_height) {
    JSAMPROW row = out.pixels.data() + size_t(guard.cinfo.output_scanline) * size_t(row_bytes);
    jpeg_read_scanlines(&guard.cinfo, &row, 1);
  }
  jpeg_finish_decompress(&guard.cinfo);
  return true;
}

// jpeg_mem_dest's output, malloc'ed by libjpeg.
struct JpegMemoryDestination {
  unsigned char* buffer = nullptr;
  unsigned long size = 0;
  ~JpegMemoryDestination() { std::free(buffer); }
};

bool encode_jpeg(const std::vector<unsigned char>& pixels, int64_t width, int64_t height, int64_t channels,
                 int quality, std::ostream& stream, std::string& error) {
  JpegMemoryDestination destination;  // freed after the compressor is destroyed
  JpegGuard<jpeg_compress_struct> guard;
  if (setjmp(guard.failure.jump)) {
    error = guard.failure.message;
    return false;
  }
  guard.create();
  jpeg_mem_dest(&guard.cinfo, &destination.buffer, &destination.size);
  guard.cinfo.image_width = JDIMENSION(width);
  guard.cinfo.image_height = JDIMENSION(height);
  guard.cinfo.input_components = int(channels);
  guard.cinfo.in_color_space = channels == 1 ? JCS_GRAYSCALE : JCS_RGB;
  jpeg_set_defaults(&guard.cinfo);  // 4:2:0 chroma, as OpenImageIO writes by default
  jpeg_set_quality(&guard.cinfo, quality, TRUE);
  jpeg_start_compress(&guard.cinfo, TRUE);
  const size_t row_bytes = size_t(width * channels);
  while (guard.cinfo.next_scanline < guard.cinfo.image_height) {
    JSAMPROW row = const_cast<JSAMPROW>(pixels.data() + size_t(guard.cinfo.next_scanline) * row_bytes);
    jpeg_write_scanlines(&guard.cinfo, &row, 1);
  }
  jpeg_finish_compress(&guard.cinfo);
  stream.write(reinterpret_cast<const char*>(destination.buffer), std::streamsize(destination.size));
  return true;
}

#else

[[noreturn]] void no_backend(const std::string& path) {
  fail(path + ": PNG/JPEG unavailable: this build found no libpng/libjpeg (Debian libpng-dev, "
              "libjpeg62-turbo-dev) and has no OpenImageIO; write safetensors instead");
}

#endif

}  // namespace

#if FLAT_WITH_PNG_JPEG

bool png_jpeg_available() { return true; }

at::Tensor read_png(const std::string& path) {
  const auto bytes = read_whole_file(path, "PNG");
  if (bytes.size() < 8 || png_sig_cmp(bytes.data(), 0, 8) != 0) {
    fail(path + ": not a PNG file (no PNG signature)");
  }
  PngImage image;
  std::string error;
  if (!decode_png(bytes, image, error)) fail(path + ": cannot read PNG: " + error);
  std::vector<uint16_t> codes(size_t(image.width * image.height * image.channels));
  const unsigned char* src = image.rows.data();
  if (image.bit_depth == 16) {
    for (size_t i = 0; i < codes.size(); ++i) codes[i] = uint16_t((src[2 * i] << 8) | src[2 * i + 1]);  // big-endian
  } else {
    std::copy(src, src + codes.size(), codes.begin());
  }
  if (image.channels == 2 || image.channels == 4) associate_alpha(codes, image.channels, image.bit_depth, image.gamma);
  return codes_to_chw(codes, image.height, image.width, image.channels, image.bit_depth);
}

at::Tensor read_jpeg(const std::string& path) {
  const auto bytes = read_whole_file(path, "JPEG");
  if (bytes.size() < 3 || bytes[0] != 0xFF || bytes[1] != 0xD8 || bytes[2] != 0xFF) {
    fail(path + ": not a JPEG file (no JPEG start-of-image marker)");
  }
  JpegImage image;
  std::string error;
  if (!decode_jpeg(bytes, image, error)) fail(path + ": cannot read JPEG: " + error);
  std::vector<uint16_t> codes(image.pixels.begin(), image.pixels.end());
  return codes_to_chw(codes, image.height, image.width, image.channels, 8);
}

void write_png(const std::string& path, const at::Tensor& chw, bool sixteen_bit) {
  check_chw(path, chw, "1 to 4", chw.defined() && chw.dim() == 3 && chw.size(0) >= 1 && chw.size(0) <= 4);
  const int bit_depth = sixteen_bit ? 16 : 8;
  const int64_t channels = chw.size(0), height = chw.size(1), width = chw.size(2);
  auto codes = chw_to_codes(chw, bit_depth);
  if (channels == 2 || channels == 4) deassociate_alpha(codes, channels, bit_depth);
  std::vector<unsigned char> rows(codes.size() * size_t(bit_depth / 8));
  if (bit_depth == 16) {
    for (size_t i = 0; i < codes.size(); ++i) {
      rows[2 * i] = static_cast<unsigned char>(codes[i] >> 8);
      rows[2 * i + 1] = static_cast<unsigned char>(codes[i] & 0xff);
    }
  } else {
    std::copy(codes.begin(), codes.end(), rows.begin());
  }
  AtomicFile file(path, ".png");
  std::string error;
  if (!encode_png(rows, width, height, channels, bit_depth, file.stream(), error)) {
    fail(path + ": cannot write PNG: " + error);
  }
  file.commit();
}

void write_jpeg(const std::string& path, const at::Tensor& chw, int quality) {
  check_chw(path, chw, "1, 3 or 4 (JPEG has no alpha: 4 drops it)",
            chw.defined() && chw.dim() == 3 && (chw.size(0) == 1 || chw.size(0) == 3 || chw.size(0) == 4));
  FLAT_CHECK(quality >= 1 && quality <= 100, path + ": JPEG quality must be 1..100, got " + std::to_string(quality));
  const at::Tensor colour = chw.size(0) == 4 ? chw.narrow(0, 0, 3) : chw;
  const int64_t channels = colour.size(0), height = colour.size(1), width = colour.size(2);
  const auto codes = chw_to_codes(colour, 8);
  const std::vector<unsigned char> pixels(codes.begin(), codes.end());
  AtomicFile file(path, ".jpg");
  std::string error;
  if (!encode_jpeg(pixels, width, height, channels, quality, file.stream(), error)) {
    fail(path + ": cannot write JPEG: " + error);
  }
  file.commit();
}

#else

bool png_jpeg_available() { return false; }
at::Tensor read_png(const std::string& path) { no_backend(path); }
at::Tensor read_jpeg(const std::string& path) { no_backend(path); }
void write_png(const std::string& path, const at::Tensor&, bool) { no_backend(path); }
void write_jpeg(const std::string& path, const at::Tensor&, int) { no_backend(path); }

#endif

}  // namespace flat
