// Image files: PNG round trips within quantisation, EXR round trips exactly;
// without OpenImageIO, PNG and JPEG go through libpng/libjpeg
// (test_png_jpeg_io.cpp) and EXR names the missing library and the path.
#include <filesystem>
#include <fstream>

#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/png_jpeg_io.h"
#include "test_support.h"

namespace fs = std::filesystem;

TEST_CASE("list_images finds image files sorted by name", "[core][image_io]") {
  auto dir = flat::test::scratch_dir("image_list");
  for (const char* name : {"b.png", "a.JPG", "c.exr", "notes.txt", "d.tif", "e.jpeg"}) std::ofstream(dir / name) << "x";
  fs::create_directories(dir / "sub.png");  // a folder, not an image
  auto images = flat::list_images(dir.string());
  REQUIRE(images.size() == 5);
  CHECK(fs::path(images[0]).filename() == "a.JPG");
  CHECK(fs::path(images[1]).filename() == "b.png");
  CHECK(fs::path(images[2]).filename() == "c.exr");
  CHECK(fs::path(images[3]).filename() == "d.tif");
  CHECK(fs::path(images[4]).filename() == "e.jpeg");
  REQUIRE_THROWS_WITH(flat::list_images((dir / "none").string()), FLAT_CONTAINS("none") && FLAT_CONTAINS("not a folder"));
}

#if FLAT_WITH_OIIO

TEST_CASE("PNG round trip within 8-bit (and 16-bit) quantisation", "[core][image_io]") {
  REQUIRE(flat::image_io_available());
  REQUIRE(flat::float_image_io_available());
  auto dir = flat::test::scratch_dir("image_png");
  auto gen = at::make_generator<at::CPUGeneratorImpl>(7);
  auto img = at::rand({3, 5, 7}, gen, at::kFloat);
  img[0][0][0] = -0.5f;  // clamped to 0
  img[1][0][0] = 1.5f;   // clamped to 1

  const std::string path8 = (dir / "rgb.png").string();
  flat::write_image(path8, img);
  auto back = flat::read_image(path8);
  REQUIRE(back.sizes() == at::IntArrayRef({3, 5, 7}));
  CHECK(back.scalar_type() == at::kFloat);
  auto clamped = img.clamp(0, 1);
  CHECK((back - clamped).abs().max().item<float>() <= 0.5f / 255 + 1e-6f);
  // quantised: every value is k/255
  CHECK(((back * 255).round() - back * 255).abs().max().item<float>() < 1e-4f);

  const std::string path16 = (dir / "rgb16.png").string();
  flat::write_image(path16, img, /*png16=*/true);
  auto back16 = flat::read_image(path16);
  CHECK((back16 - clamped).abs().max().item<float>() <= 0.5f / 65535 + 1e-6f);

  // One channel works too; no temp files are left.
  flat::write_image((dir / "gray.png").string(), img.slice(0, 0, 1));
  CHECK(flat::read_image((dir / "gray.png").string()).size(0) == 1);
  CHECK(flat::list_images(dir.string()).size() == 3);
  size_t files = 0;
  for (const auto& item : fs::directory_iterator(dir)) files += item.is_regular_file();
  CHECK(files == 3);
}

TEST_CASE("EXR round trip is exact and keeps values outside [0,1]", "[core][image_io]") {
  auto dir = flat::test::scratch_dir("image_exr");
  auto gen = at::make_generator<at::CPUGeneratorImpl>(8);
  auto depth = at::randn({1, 4, 6}, gen, at::kFloat) * 10;
  const std::string path = (dir / "depth.exr").string();
  flat::write_image(path, depth);
  auto back = flat::read_image(path);
  REQUIRE(back.sizes() == depth.sizes());
  CHECK(at::equal(back, depth));

  auto normals = at::randn({3, 2, 3}, gen, at::kFloat);
  flat::write_image((dir / "normals.exr").string(), normals);
  CHECK(at::equal(flat::read_image((dir / "normals.exr").string()), normals));
}

TEST_CASE("image errors name the path", "[core][image_io]") {
  auto dir = flat::test::scratch_dir("image_errors");
  const std::string missing = (dir / "missing.png").string();
  REQUIRE_THROWS_WITH(flat::read_image(missing), FLAT_CONTAINS(missing) && FLAT_CONTAINS("no such image"));
  const std::string garbage = (dir / "garbage.png").string();
  std::ofstream(garbage) << "not a png";
  REQUIRE_THROWS_WITH(flat::read_image(garbage), FLAT_CONTAINS(garbage));
  REQUIRE_THROWS_WITH(flat::write_image((dir / "x.png").string(), at::zeros({5, 2, 2})),
                      FLAT_CONTAINS("x.png") && FLAT_CONTAINS("(C,H,W)") && FLAT_CONTAINS("(5,2,2)"));
  REQUIRE_THROWS_WITH(flat::write_image((dir / "x.bmpx").string(), at::zeros({3, 2, 2})),
                      FLAT_CONTAINS("unsupported image extension"));
  // A failed write leaves a good file alone.
  const std::string good = (dir / "good.png").string();
  flat::write_image(good, at::ones({3, 2, 2}));
  REQUIRE_THROWS(flat::write_image(good, at::ones({2, 2})));
  CHECK(at::equal(flat::read_image(good), at::ones({3, 2, 2})));
}

#else  // built with -DFLAT_WITH_OIIO=OFF

TEST_CASE("without OpenImageIO, PNG and JPEG work through libpng/libjpeg; EXR fails naming the path",
          "[core][image_io]") {
  CHECK(!flat::float_image_io_available());
  if (!flat::png_jpeg_available()) {
    CHECK(!flat::image_io_available());
    REQUIRE_THROWS_WITH(flat::read_image("in/view_000.png"),
                        FLAT_CONTAINS("image IO unavailable: this build has no OpenImageIO (-DFLAT_WITH_OIIO=OFF)") &&
                            FLAT_CONTAINS("write safetensors instead") && FLAT_CONTAINS("in/view_000.png"));
    REQUIRE_THROWS_WITH(flat::write_image("out/render.png", at::zeros({3, 2, 2})),
                        FLAT_CONTAINS("image IO unavailable") && FLAT_CONTAINS("out/render.png"));
    return;
  }
  CHECK(flat::image_io_available());
  auto dir = flat::test::scratch_dir("image_no_oiio");
  auto gen = at::make_generator<at::CPUGeneratorImpl>(7);
  auto img = at::rand({3, 5, 7}, gen, at::kFloat);
  const std::string png = (dir / "rgb.png").string(), png16 = (dir / "rgb16.PNG").string();
  flat::write_image(png, img);
  auto back = flat::read_image(png);
  REQUIRE(back.sizes() == at::IntArrayRef({3, 5, 7}));
  CHECK((back - img).abs().max().item<float>() <= 0.5f / 255 + 1e-6f);
  flat::write_image(png16, img, /*png16=*/true);
  CHECK((flat::read_image(png16) - img).abs().max().item<float>() <= 0.5f / 65535 + 1e-6f);
  const std::string jpg = (dir / "rgb.jpg").string();
  flat::write_image(jpg, at::full({3, 16, 16}, 0.5f));
  auto jback = flat::read_image(jpg);
  REQUIRE(jback.sizes() == at::IntArrayRef({3, 16, 16}));
  CHECK((jback - 0.5f).abs().max().item<float>() < 0.01f);

  const std::string exr = (dir / "depth.exr").string();
  REQUIRE_THROWS_WITH(flat::write_image(exr, at::zeros({1, 2, 2})),
                      FLAT_CONTAINS(exr) && FLAT_CONTAINS("-DFLAT_WITH_OIIO=OFF") && FLAT_CONTAINS(".safetensors"));
  CHECK(!fs::exists(exr));
  std::ofstream(exr) << "x";
  REQUIRE_THROWS_WITH(flat::read_image(exr), FLAT_CONTAINS(exr) && FLAT_CONTAINS("EXR"));
  REQUIRE_THROWS_WITH(flat::write_image((dir / "x.bmpx").string(), at::zeros({3, 2, 2})),
                      FLAT_CONTAINS("unsupported image extension"));
  const std::string garbage = (dir / "garbage.png").string();
  std::ofstream(garbage) << "not a png";
  REQUIRE_THROWS_WITH(flat::read_image(garbage), FLAT_CONTAINS(garbage) && FLAT_CONTAINS("not a PNG"));
  // Previews are PNG again.
  CHECK(flat::write_preview_image(img, (dir / "grid").string()) == (dir / "grid.png").string());
}

#endif
