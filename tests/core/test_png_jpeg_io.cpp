// The libpng/libjpeg backend (core/png_jpeg_io.h), which read_image and
// write_image use when the build has no OpenImageIO. Hand-made PNGs (written
// here with uncompressed deflate blocks, no libpng) decode to the codes that
// OpenImageIO 2.4 gives for them (printed by `oiiotool --dumpdata`); in the
// OpenImageIO build every file written by one library reads back identically
// through the other. Corrupt, truncated and mislabelled files throw a
// flat::Error naming the file; refused tensors leave no file behind.
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/png_jpeg_io.h"
#include "support/read_file.h"
#include "test_support.h"

namespace fs = std::filesystem;
using flat::test::read_file;

namespace {

#define REQUIRE_PNG_JPEG()                                                                           \
  do {                                                                                               \
    if (!flat::png_jpeg_available()) FLAT_SKIP("built without libpng/libjpeg (libpng-dev, libjpeg62-turbo-dev)"); \
  } while (0)

void write_bytes(const fs::path& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary) << bytes;
}

// ---- a minimal PNG writer of its own (stored deflate blocks), to make files libpng did not write

uint32_t crc32(const std::string& bytes) {
  uint32_t crc = 0xffffffffu;
  for (unsigned char b : bytes) {
    crc ^= b;
    for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xedb88320u & (0u - (crc & 1u)));
  }
  return crc ^ 0xffffffffu;
}

std::string be32(uint32_t v) {
  return {char(v >> 24), char((v >> 16) & 0xff), char((v >> 8) & 0xff), char(v & 0xff)};
}

std::string be16(uint32_t v) { return {char((v >> 8) & 0xff), char(v & 0xff)}; }

std::string chunk(const std::string& type, const std::string& data) {
  return be32(uint32_t(data.size())) + type + data + be32(crc32(type + data));
}

std::string gama_chunk(uint32_t gamma_times_100000) { return chunk("gAMA", be32(gamma_times_100000)); }

// `rows`: each row's bytes without the filter byte (filter 0 is added).
std::string make_png(uint32_t width, uint32_t height, int depth, int color_type, const std::vector<std::string>& rows,
                     const std::string& extra_chunks = "") {
  std::string raw;
  for (const auto& row : rows) raw += std::string(1, '\0') + row;
  REQUIRE(raw.size() < 65536);
  uint32_t a = 1, b = 0;  // Adler-32 of the uncompressed data
  for (unsigned char c : raw) {
    a = (a + c) % 65521;
    b = (b + a) % 65521;
  }
  const uint32_t len = uint32_t(raw.size());
  std::string zlib = std::string("\x78\x01", 2) + std::string(1, '\x01') + char(len & 0xff) + char(len >> 8) +
                     char(~len & 0xff) + char((~len >> 8) & 0xff) + raw + be32((b << 16) | a);
  std::string ihdr = be32(width) + be32(height) + char(depth) + char(color_type) + std::string(3, '\0');
  return std::string("\x89PNG\r\n\x1a\n", 8) + chunk("IHDR", ihdr) + extra_chunks + chunk("IDAT", zlib) +
         chunk("IEND", "");
}

#if FLAT_WITH_OIIO
// A PNG with `extra` chunks inserted right after IHDR (8-byte signature + 25-byte IHDR).
std::string with_chunks_after_ihdr(const std::string& png, const std::string& extra) {
  return png.substr(0, 33) + extra + png.substr(33);
}
#endif

// Codes in (H,W,C) order -> the (C,H,W) float32 image OpenImageIO returns (code times 1/max).
at::Tensor from_codes(const std::vector<int>& codes, int64_t channels, int64_t height, int64_t width, int bits) {
  const float scale = bits == 16 ? 1.0f / 65535.0f : 1.0f / 255.0f;
  auto hwc = at::empty({height, width, channels}, at::kFloat);
  REQUIRE(int64_t(codes.size()) == hwc.numel());
  for (size_t i = 0; i < codes.size(); ++i) hwc.data_ptr<float>()[i] = float(codes[i]) * scale;
  return hwc.permute({2, 0, 1}).contiguous();
}

// What a writer stores for `img` without alpha: clamp, NaN -> 0, round half up.
at::Tensor quantised(const at::Tensor& img, int bits) {
  const float max = bits == 16 ? 65535.0f : 255.0f;
  auto hwc = at::nan_to_num(img, 0.0, 1.0, 0.0).clamp(0, 1).permute({1, 2, 0}).contiguous();
  std::vector<int> codes(size_t(hwc.numel()));
  for (size_t i = 0; i < codes.size(); ++i) codes[i] = int(hwc.data_ptr<float>()[i] * max + 0.5f);
  return from_codes(codes, img.size(0), img.size(1), img.size(2), bits);
}

// Random colours with alpha (last channel, if any) in [0,1], colour already
// multiplied by alpha (what read_image returns); a few pixels fully transparent.
at::Tensor random_image(int64_t channels, int64_t height, int64_t width, uint64_t seed) {
  auto gen = at::make_generator<at::CPUGeneratorImpl>(seed);
  auto img = at::rand({channels, height, width}, gen, at::kFloat);
  if (channels == 2 || channels == 4) {
    auto alpha = img[channels - 1];
    alpha[0][0] = 0.0f;
    alpha[0][1] = 1.0f;
    img.narrow(0, 0, channels - 1).mul_(alpha.unsqueeze(0));
  }
  return img;
}

// A smooth colour image (JPEG's kind of content).
at::Tensor smooth_image(int64_t channels, int64_t height, int64_t width) {
  auto y = at::linspace(0, 1, height, at::kFloat).view({1, height, 1});
  auto x = at::linspace(0, 1, width, at::kFloat).view({1, 1, width});
  auto c = at::arange(channels, at::kFloat).view({channels, 1, 1});
  return (0.5 + 0.4 * at::sin(3.0 * x + 2.0 * y + c)).contiguous();
}

float max_abs(const at::Tensor& a, const at::Tensor& b) { return (a - b).abs().max().item<float>(); }

// fn(bits, channels) for every PNG layout: 8 and 16 bit, gray, gray+alpha,
// RGB and RGBA; a failure names the layout.
void for_each_png_layout(const std::function<void(int, int64_t)>& fn) {
  for (int bits : {8, 16})
    for (int64_t channels = 1; channels <= 4; ++channels) {
      INFO("bits " << bits << ", channels " << channels);
      fn(bits, channels);
    }
}

}  // namespace

TEST_CASE("hand-made PNGs decode to OpenImageIO 2.4's values", "[core][png_jpeg]") {
  REQUIRE_PNG_JPEG();
  auto dir = flat::test::scratch_dir("png_handmade");
  const std::string rgba_row = std::string("\xc8\x64\x32\xff" "\xc8\x64\x32\x80" "\xc8\x64\x32\x00" "\xc8\x64\x32\x40", 16);
  struct Case {
    const char* name;
    std::string bytes;
    int64_t channels, width;
    int bits;
    std::vector<int> codes;  // `oiiotool --dumpdata` of the file (OpenImageIO 2.4.7)
  };
  const std::vector<Case> cases = {
      // (200,100,50) at alpha 255/128/0/64: colour associated in integers (truncated).
      {"rgba8.png", make_png(4, 1, 8, 6, {rgba_row}), 4, 4, 8,
       {200, 100, 50, 255, 100, 50, 25, 128, 0, 0, 0, 0, 50, 25, 12, 64}},
      // With gAMA 1/2.2: colour times (alpha/255)^2.2.
      {"rgba8_gamma.png", make_png(4, 1, 8, 6, {rgba_row}, gama_chunk(45455)), 4, 4, 8,
       {200, 100, 50, 255, 43, 21, 10, 128, 0, 0, 0, 0, 9, 4, 2, 64}},
      // sRGB wins over gAMA: plain association again.
      {"rgba8_srgb.png", make_png(4, 1, 8, 6, {rgba_row}, chunk("sRGB", std::string(1, '\0')) + gama_chunk(45455)), 4,
       4, 8, {200, 100, 50, 255, 100, 50, 25, 128, 0, 0, 0, 0, 50, 25, 12, 64}},
      {"ga8.png", make_png(2, 1, 8, 4, {std::string("\xc8\x80\x64\x40", 4)}), 2, 2, 8, {100, 128, 25, 64}},
      {"ga16.png", make_png(1, 1, 16, 4, {be16(60000) + be16(30000)}), 2, 1, 16, {27466, 30000}},
      {"rgba16_gamma.png",
       make_png(2, 1, 16, 6,
                {be16(51400) + be16(25700) + be16(12850) + be16(32896) + be16(51400) + be16(25700) + be16(12850) +
                 be16(16448)},
                gama_chunk(45455)),
       4, 2, 16, {11283, 5641, 2820, 32896, 2455, 1227, 613, 16448}},
      // Palette with tRNS -> RGBA; gray with tRNS -> gray + alpha; 4-bit gray scaled to 8 bit.
      {"palette_trns.png",
       make_png(2, 1, 8, 3, {std::string("\x00\x01", 2)},
                chunk("PLTE", std::string("\xc8\x64\x32\x0a\x14\x1e", 6)) + chunk("tRNS", std::string("\x80", 1))),
       4, 2, 8, {100, 50, 25, 128, 10, 20, 30, 255}},
      {"gray_trns.png", make_png(2, 1, 8, 0, {std::string("\x07\x09", 2)}, chunk("tRNS", be16(7))), 2, 2, 8,
       {0, 0, 9, 255}},
      {"gray4.png", make_png(2, 1, 4, 0, {std::string("\x3f", 1)}), 1, 2, 8, {51, 255}},
      {"rgb16.png", make_png(1, 1, 16, 2, {be16(1) + be16(32768) + be16(65535)}), 3, 1, 16, {1, 32768, 65535}},
  };
  for (const auto& c : cases) {
    INFO(c.name);
    const std::string path = (dir / c.name).string();
    write_bytes(path, c.bytes);
    const auto expected = from_codes(c.codes, c.channels, 1, c.width, c.bits);
    const auto got = flat::read_png(path);
    REQUIRE(got.sizes() == expected.sizes());
    CHECK(got.scalar_type() == at::kFloat);
    CHECK(at::equal(got, expected));
    CHECK(at::equal(flat::read_image(path), expected));  // OpenImageIO, or the backend without it
  }
}

TEST_CASE("PNG round trip: 8 and 16 bit, gray, gray+alpha, RGB, RGBA", "[core][png_jpeg]") {
  REQUIRE_PNG_JPEG();
  auto dir = flat::test::scratch_dir("png_roundtrip");
  for_each_png_layout([&](int bits, int64_t channels) {
    auto img = random_image(channels, 5, 7, 10 + channels);
    const bool alpha = channels == 2 || channels == 4;
    if (alpha) img[channels - 1].fill_(1.0f);  // opaque: stored exactly as quantised
    img[0][1][1] = -0.5f;                       // clamped to 0
    img[0][1][2] = 1.5f;                        // clamped to 1
    img[0][1][3] = std::numeric_limits<float>::quiet_NaN();  // written as 0
    const std::string path = (dir / ("img" + std::to_string(bits) + "_" + std::to_string(channels) + ".png")).string();
    flat::write_png(path, img, bits == 16);
    auto back = flat::read_png(path);
    REQUIRE(back.sizes() == img.sizes());
    CHECK(at::equal(back, quantised(img, bits)));
    CHECK(back[0][1][3].item<float>() == 0.0f);
    // The file is what was asked for: bit depth (IHDR byte 24) and colour type (byte 25).
    const std::string bytes = read_file(path);
    CHECK(int(bytes[24]) == bits);
    CHECK(int(bytes[25]) == (channels == 1 ? 0 : channels == 2 ? 4 : channels == 3 ? 2 : 6));
  });
  // With alpha < 1, colour is stored divided by alpha and multiplied back on
  // reading: the round trip keeps associated colour to a few codes.
  for (int bits : {8, 16}) {
    auto img = random_image(4, 6, 9, 3);
    img[3].clamp_min_(0.5f);
    img[3][0][0] = 0.0f;
    const std::string path = (dir / ("assoc" + std::to_string(bits) + ".png")).string();
    flat::write_png(path, img, bits == 16);
    auto back = flat::read_png(path);
    const float code = bits == 16 ? 1.0f / 65535 : 1.0f / 255;
    CHECK(max_abs(back, img) <= 3 * code);
    CHECK(back[0][0][0].item<float>() == 0.0f);  // transparent pixel: colour 0
    // 16 bit is closer than 8 bit: the depth is really used.
    if (bits == 16) CHECK(max_abs(back, img) < 1.0f / 255 / 4);
  }
  // Only the written files are left (no temp files).
  size_t files = 0;
  for (const auto& item : fs::directory_iterator(dir)) files += item.is_regular_file();
  CHECK(files == 10);
}

TEST_CASE("JPEG round trip within tolerance: RGB, gray, RGBA drops alpha, quality honoured", "[core][png_jpeg]") {
  REQUIRE_PNG_JPEG();
  auto dir = flat::test::scratch_dir("jpeg_roundtrip");
  const auto rgb = smooth_image(3, 32, 48);
  const std::string path = (dir / "rgb.jpg").string();
  flat::write_jpeg(path, rgb);
  auto back = flat::read_jpeg(path);
  REQUIRE(back.sizes() == rgb.sizes());
  CHECK(back.scalar_type() == at::kFloat);
  CHECK(max_abs(back, rgb) < 0.05f);
  CHECK((back - rgb).abs().mean().item<float>() < 0.01f);
  CHECK(at::equal(back, quantised(back, 8)));  // 8-bit codes times 1/255
  CHECK(read_file(path).substr(0, 3) == std::string("\xff\xd8\xff", 3));

  const auto gray = smooth_image(1, 32, 48);
  flat::write_jpeg((dir / "gray.jpeg").string(), gray);
  auto gray_back = flat::read_jpeg((dir / "gray.jpeg").string());
  REQUIRE(gray_back.sizes() == gray.sizes());
  CHECK(max_abs(gray_back, gray) < 0.05f);

  auto rgba = at::cat({rgb, at::full({1, 32, 48}, 0.25f)}, 0);
  flat::write_jpeg((dir / "rgba.jpg").string(), rgba);
  auto rgba_back = flat::read_jpeg((dir / "rgba.jpg").string());
  REQUIRE(rgba_back.size(0) == 3);
  CHECK(at::equal(rgba_back, back));

  flat::write_jpeg((dir / "q10.jpg").string(), rgb, 10);
  auto q10 = flat::read_jpeg((dir / "q10.jpg").string());
  CHECK(fs::file_size(dir / "q10.jpg") < fs::file_size(path));
  CHECK((q10 - rgb).abs().mean().item<float>() > (back - rgb).abs().mean().item<float>());
}

TEST_CASE("corrupt, truncated and mislabelled PNG/JPEG files throw flat::Error naming the file", "[core][png_jpeg]") {
  REQUIRE_PNG_JPEG();
  auto dir = flat::test::scratch_dir("png_jpeg_errors");
  const auto noise = random_image(3, 48, 64, 5);  // noise compresses badly: the data are most of the file
  const std::string png = (dir / "good.png").string(), jpg = (dir / "good.jpg").string();
  flat::write_png(png, noise);
  flat::write_jpeg(jpg, noise);
  const std::string png_bytes = read_file(png), jpg_bytes = read_file(jpg);
  REQUIRE(png_bytes.size() > 4000);
  REQUIRE(jpg_bytes.size() > 4000);

  const bool no_oiio = !flat::float_image_io_available();  // read_image is the backend there
  auto refused = [&](const std::string& name, const std::string& bytes, bool is_png, const std::string& what) {
    INFO(name);
    const std::string path = (dir / name).string();
    write_bytes(path, bytes);
    if (is_png) {
      REQUIRE_THROWS_AS(flat::read_png(path), flat::Error);
      REQUIRE_THROWS_WITH(flat::read_png(path), FLAT_CONTAINS(path) && FLAT_CONTAINS(what));
    } else {
      REQUIRE_THROWS_AS(flat::read_jpeg(path), flat::Error);
      REQUIRE_THROWS_WITH(flat::read_jpeg(path), FLAT_CONTAINS(path) && FLAT_CONTAINS(what));
    }
    if (no_oiio) REQUIRE_THROWS_WITH(flat::read_image(path), FLAT_CONTAINS(path) && FLAT_CONTAINS(what));
  };
  refused("half.png", png_bytes.substr(0, png_bytes.size() / 2), true, "cannot read PNG");
  refused("in_header.png", png_bytes.substr(0, 20), true, "cannot read PNG");
  refused("no_iend.png", png_bytes.substr(0, png_bytes.size() - 12), true, "cannot read PNG");
  std::string flipped = png_bytes;
  flipped[png_bytes.size() / 2] = char(flipped[png_bytes.size() / 2] ^ 0x55);  // inside IDAT: CRC mismatch
  refused("flipped.png", flipped, true, "cannot read PNG");
  refused("text.png", "this is not a picture\n", true, "not a PNG");
  refused("jpeg_named.png", jpg_bytes, true, "not a PNG");
  refused("empty.png", "", true, "empty file");
  refused("half.jpg", jpg_bytes.substr(0, jpg_bytes.size() / 2), false, "Premature end of JPEG file");
  refused("in_header.jpeg", jpg_bytes.substr(0, 100), false, "cannot read JPEG");
  refused("text.jpg", "this is not a picture\n", false, "not a JPEG");
  refused("png_named.jpg", png_bytes, false, "not a JPEG");

  const std::string missing = (dir / "missing.png").string();
  REQUIRE_THROWS_WITH(flat::read_png(missing), FLAT_CONTAINS(missing) && FLAT_CONTAINS("no such image file"));
  REQUIRE_THROWS_WITH(flat::read_jpeg((dir / "missing.jpg").string()), FLAT_CONTAINS("missing.jpg"));
  fs::create_directories(dir / "folder.png");
  REQUIRE_THROWS_WITH(flat::read_png((dir / "folder.png").string()), FLAT_CONTAINS("is a directory"));
  // The good files still read after all that (no state left behind).
  CHECK(at::equal(flat::read_png(png), quantised(noise, 8)));
  CHECK(flat::read_jpeg(jpg).sizes() == noise.sizes());
}

TEST_CASE("a tensor of the wrong shape or channel count is refused and writes nothing", "[core][png_jpeg]") {
  REQUIRE_PNG_JPEG();
  auto dir = flat::test::scratch_dir("png_jpeg_shapes");
  const std::string png = (dir / "x.png").string(), jpg = (dir / "x.jpg").string();
  REQUIRE_THROWS_WITH(flat::write_png(png, at::zeros({5, 2, 2})),
                      FLAT_CONTAINS(png) && FLAT_CONTAINS("(C,H,W)") && FLAT_CONTAINS("(5,2,2)"));
  REQUIRE_THROWS_WITH(flat::write_png(png, at::zeros({0, 2, 2})), FLAT_CONTAINS("(0,2,2)"));
  REQUIRE_THROWS_WITH(flat::write_png(png, at::zeros({2, 2})), FLAT_CONTAINS("(2,2)"));
  REQUIRE_THROWS_WITH(flat::write_png(png, at::zeros({3, 0, 4})), FLAT_CONTAINS("empty image"));
  REQUIRE_THROWS_WITH(flat::write_jpeg(jpg, at::zeros({2, 4, 4})),
                      FLAT_CONTAINS(jpg) && FLAT_CONTAINS("1, 3 or 4") && FLAT_CONTAINS("(2,4,4)"));
  REQUIRE_THROWS_WITH(flat::write_jpeg(jpg, at::zeros({5, 4, 4})), FLAT_CONTAINS("(5,4,4)"));
  REQUIRE_THROWS_WITH(flat::write_jpeg(jpg, at::zeros({3, 4, 4}), 0), FLAT_CONTAINS("quality"));
  CHECK(fs::is_empty(dir));
  // A refused write leaves a good file alone.
  flat::write_png(png, at::ones({3, 2, 2}));
  REQUIRE_THROWS(flat::write_png(png, at::ones({6, 2, 2})));
  CHECK(at::equal(flat::read_png(png), at::ones({3, 2, 2})));
}

#if FLAT_WITH_OIIO

TEST_CASE("PNG: the backend and OpenImageIO read each other's files identically", "[core][png_jpeg][oiio]") {
  REQUIRE_PNG_JPEG();
  auto dir = flat::test::scratch_dir("png_vs_oiio");
  for_each_png_layout([&](int bits, int64_t channels) {
    auto img = random_image(channels, 13, 17, 100 + 10 * bits + channels);
    if (channels == 4) img[0][2][2] = 0.9f;  // colour above alpha: clamped after the division
    const std::string stem = std::to_string(bits) + "_" + std::to_string(channels);
    const std::string ours = (dir / ("ours" + stem + ".png")).string();
    const std::string theirs = (dir / ("oiio" + stem + ".png")).string();
    flat::write_png(ours, img, bits == 16);
    flat::write_image(theirs, img, bits == 16);  // OpenImageIO
    const auto ours_by_us = flat::read_png(ours), ours_by_oiio = flat::read_image(ours);
    const auto theirs_by_us = flat::read_png(theirs), theirs_by_oiio = flat::read_image(theirs);
    CHECK(at::equal(ours_by_us, ours_by_oiio));
    CHECK(at::equal(theirs_by_us, theirs_by_oiio));
    CHECK(at::equal(ours_by_us, theirs_by_us));  // the two writers store the same codes
    if (channels == 4) {
      // With a gAMA chunk (1/2.2) OpenImageIO associates with alpha^2.2: so does the backend.
      const std::string gamma = (dir / ("gamma" + stem + ".png")).string();
      write_bytes(gamma, with_chunks_after_ihdr(read_file(ours), gama_chunk(45455)));
      const auto gamma_by_us = flat::read_png(gamma);
      CHECK(at::equal(gamma_by_us, flat::read_image(gamma)));
      CHECK_FALSE(at::equal(gamma_by_us, ours_by_us));  // the chunk was read and changed the colours
    }
  });
}

TEST_CASE("JPEG: the backend and OpenImageIO read each other's files alike", "[core][png_jpeg][oiio]") {
  REQUIRE_PNG_JPEG();
  auto dir = flat::test::scratch_dir("jpeg_vs_oiio");
  for (int64_t channels : {1, 3}) {
    INFO("channels " << channels);
    const auto img = smooth_image(channels, 24, 40);
    const std::string ours = (dir / ("ours" + std::to_string(channels) + ".jpg")).string();
    const std::string theirs = (dir / ("oiio" + std::to_string(channels) + ".jpg")).string();
    flat::write_jpeg(ours, img);
    flat::write_image(theirs, img);  // OpenImageIO, its default quality
    const auto ours_by_us = flat::read_jpeg(ours), ours_by_oiio = flat::read_image(ours);
    const auto theirs_by_us = flat::read_jpeg(theirs), theirs_by_oiio = flat::read_image(theirs);
    REQUIRE(ours_by_oiio.sizes() == img.sizes());
    REQUIRE(theirs_by_us.sizes() == img.sizes());
    // One libjpeg decodes both ways: at most one code apart (the same in practice).
    CHECK(max_abs(ours_by_us, ours_by_oiio) <= 1.0f / 255 + 1e-6f);
    CHECK(max_abs(theirs_by_us, theirs_by_oiio) <= 1.0f / 255 + 1e-6f);
    // The two encoders, at the same quality, give nearly the same pictures.
    CHECK(max_abs(ours_by_us, theirs_by_us) <= 2.0f / 255 + 1e-6f);
    CHECK(max_abs(ours_by_us, img) < 0.05f);
  }
}

#endif
