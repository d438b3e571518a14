// Depth and normals from external predictors attached by the importers
// (include/flat/data/geometry_maps.h): a tiny RealEstate10K clip and a
// transforms.json capture rendered from a synthetic room, whose exact depth
// and OpenCV normals are known, written in every supported file kind and
// convention; after import the stored maps must equal the known ones (times
// the metric scale), and each defect must fail naming its file or frame.
#include <filesystem>
#include <fstream>
#include <functional>
#include <iomanip>

#include <nlohmann/json.hpp>

#include "flat/camera/cameras.h"
#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/npy.h"
#include "flat/data/frame_io.h"
#include "flat/data/frame_resize.h"
#include "flat/data/geometry_maps.h"
#include "flat/data/importers.h"
#include "flat/data/scene_frames.h"
#include "flat/data/synthetic_scene.h"
#include "flat/data/undistort.h"
#include "data_test_dirs.h"
#include "support/error_of.h"
#include "support/read_file.h"
#include "test_support.h"

using namespace flat;
using flat::test::error_of;
namespace fs = std::filesystem;

namespace {

const bool kSingleThread = (at::set_num_threads(1), true);

constexpr int64_t kFrames = 4, kH = 12, kW = 16;

data::SynthScene room() {
  data::SynthOptions o;
  o.family = "room";
  o.motion = "pan";
  o.frames = kFrames;
  o.height = kH;
  o.width = kW;
  o.seed = 11;
  return data::render_synthetic_scene(o);
}

// OpenCV (y down, z forward) <-> OpenGL (y up, z backward): negate y and z.
at::Tensor flip_yz(const at::Tensor& n) {
  auto m = n.clone();
  m.narrow(-3, 1, 2).neg_();
  return m;
}

std::string timestamp(int64_t i) { return std::to_string(1000000 + 33366 * i); }

// A RealEstate10K clip in the fresh folder `name` (returned): cams.txt and frames/<timestamp>.png.
fs::path write_re10k(const std::string& name, const data::SynthScene& s) {
  const fs::path root = test::fresh_dir(name);
  fs::create_directories(root / "frames");
  std::ofstream txt(root / "cams.txt");
  txt << "https://www.youtube.com/watch?v=xxxxxxxxxxx\n" << std::setprecision(17);
  auto w2c = camera::world_to_camera(s.cameras.c2w).to(torch::kDouble);
  for (int64_t i = 0; i < kFrames; ++i) {
    txt << timestamp(i);
    for (int k = 0; k < 4; ++k) txt << " " << s.cameras.intrinsics[i][k].item<double>();
    txt << " 0 0";
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) txt << " " << w2c[i][r][c].item<double>();
    txt << "\n";
    data::write_rgb((root / "frames" / (timestamp(i) + ".png")).string(), s.images[i]);
  }
  return root;
}

// A NeRF capture in the fresh folder `name` (returned): capture/transforms.json
// (OpenGL c2w) and capture/images/f<i>.png.
fs::path write_transforms(const std::string& name, const data::SynthScene& s, double k1 = 0) {
  const fs::path root = test::fresh_dir(name);
  nlohmann::json doc;
  doc["w"] = kW;
  doc["h"] = kH;
  doc["fl_x"] = s.cameras.intrinsics[0][0].item<double>() * kW;
  doc["fl_y"] = s.cameras.intrinsics[0][1].item<double>() * kH;
  doc["cx"] = s.cameras.intrinsics[0][2].item<double>() * kW;
  doc["cy"] = s.cameras.intrinsics[0][3].item<double>() * kH;
  if (k1 != 0) doc["k1"] = k1;
  fs::create_directories(root / "capture" / "images");
  for (int64_t i = 0; i < kFrames; ++i) {
    auto m = s.cameras.c2w[i].to(torch::kDouble).clone();
    m.select(1, 1).slice(0, 0, 3).neg_();  // OpenCV -> OpenGL camera axes
    m.select(1, 2).slice(0, 0, 3).neg_();
    nlohmann::json rows = nlohmann::json::array();
    for (int r = 0; r < 4; ++r)
      rows.push_back({m[r][0].item<double>(), m[r][1].item<double>(), m[r][2].item<double>(), m[r][3].item<double>()});
    std::string file = "images/f" + std::to_string(i) + ".png";
    data::write_rgb((root / "capture" / file).string(), s.images[i]);
    doc["frames"].push_back({{"file_path", file}, {"transform_matrix", rows}});
  }
  std::ofstream(root / "capture" / "transforms.json") << doc.dump();
  return root;
}

// Normals as an 8-bit PNG in the 0.5 n + 0.5 encoding.
void write_normals_png(const fs::path& path, const at::Tensor& n) { write_image(path.string(), n * 0.5 + 0.5); }

// EXR needs OpenImageIO (a build with only libpng/libjpeg reads PNG but not EXR).
bool exr_available() {
  try {
    write_image((test::fresh_dir("geo_exr_probe") / "probe.exr").string(), at::zeros({1, 1, 1}));
    return true;
  } catch (const Error&) {
    return false;
  }
}

// Import options with the metric scale that read the depth and normal maps
// from depth/ and normals/ in `root` (made here, empty).
data::ImportOptions with_map_folders(const fs::path& root, double metric_scale) {
  fs::create_directories(root / "depth");
  fs::create_directories(root / "normals");
  data::ImportOptions o;
  o.metric_scale = metric_scale;
  o.geometry.depth_dir = (root / "depth").string();
  o.geometry.normals_dir = (root / "normals").string();
  return o;
}

data::FrameBatch load_all(const std::string& dir, bool depth = true, bool normals = true) {
  std::vector<int64_t> all;
  for (int64_t i = 0; i < kFrames; ++i) all.push_back(i);
  return data::load_frames(data::read_scene(dir), all, depth, normals);
}

}  // namespace

TEST_CASE("geometry maps: RE10K with NPY depth and OpenGL 8-bit PNG normals", "[data][geometry_maps]") {
  if (!image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the clip is written as PNG");
  auto s = room();
  const fs::path root = write_re10k("geo_re10k", s);
  auto o = with_map_folders(root, 0.5);
  o.geometry.normals_convention = "opengl";
  for (int64_t i = 0; i < kFrames; ++i) {
    write_npy((root / "depth" / (timestamp(i) + ".npy")).string(), s.depth[i][0]);  // (H,W) float32
    write_normals_png(root / "normals" / (timestamp(i) + ".png"), flip_yz(s.normals[i]));
  }
  REQUIRE(s.depth.min().item<float>() > 0);  // a closed room: every pixel known
  auto scene = data::import_re10k((root / "cams.txt").string(), (root / "frames").string(), (root / "scene").string(), o);
  CHECK(scene.has_depth);
  CHECK(scene.has_normals);
  CHECK_THAT(scene.depth_source, FLAT_CONTAINS("npy files from " + fs::absolute(root / "depth").lexically_normal().string()));
  CHECK_THAT(scene.depth_source, FLAT_CONTAINS("(metric scale 0.5)"));
  CHECK_THAT(scene.normals_source, FLAT_CONTAINS("png files from "));
  CHECK_THAT(scene.normals_source, FLAT_CONTAINS("opengl -> opencv"));
  auto back = data::read_scene((root / "scene").string());
  CHECK(back.depth_source == scene.depth_source);
  CHECK(back.normals_source == scene.normals_source);

  auto f = load_all((root / "scene").string());
  // Depth: the known depth times the metric scale (float32 exact up to rounding).
  CHECK(torch::allclose(f.depth, s.depth * 0.5, 1e-6, 1e-6));
  CHECK((f.depth - s.depth).abs().max().item<float>() > 0.1);  // the scale was applied
  // Normals: the known OpenCV normals, up to 8-bit quantisation; without the y/z flip they would be far off.
  const float err = (f.normals - s.normals).abs().max().item<float>();
  INFO("max normal error " << err);
  CHECK(err < 0.02f);
  CHECK((f.normals - flip_yz(s.normals)).abs().max().item<float>() > 0.5f);
  CHECK((f.normals.norm(2, 1) - 1).abs().max().item<float>() < 1e-5f);  // renormalised after decoding

  // Metric depth beside scale-free poses (MapAnything's depth, RealEstate10K's
  // poses): --depth-metric keeps the depth as given and scales the poses only.
  o.geometry.depth_metric = true;
  auto metric = data::import_re10k((root / "cams.txt").string(), (root / "frames").string(),
                                   (root / "scene_metric").string(), o);
  CHECK_THAT(metric.depth_source, FLAT_CONTAINS("metric as given"));
  auto g = load_all((root / "scene_metric").string());
  CHECK(torch::allclose(g.depth, s.depth, 1e-6, 1e-6));
  CHECK(torch::allclose(metric.cameras().c2w, scene.cameras().c2w, 1e-6, 1e-6));  // the poses scaled as before
}

TEST_CASE("geometry maps: transforms.json with 16-bit PNG depth and OpenCV NPY normals", "[data][geometry_maps]") {
  if (!image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the capture is written as PNG");
  auto s = room();
  const fs::path root = write_transforms("geo_transforms", s);
  auto o = with_map_folders(root, 2.0);
  const double unit = 0.001;  // millimetres
  o.geometry.depth_png_scale = unit;
  auto units = (s.depth / unit).round();
  REQUIRE(units.max().item<float>() < 65535);
  for (int64_t i = 0; i < kFrames; ++i) {
    write_image((root / "depth" / ("f" + std::to_string(i) + ".png")).string(), units[i] / 65535.0, /*png16*/ true);
    write_npy((root / "normals" / ("f" + std::to_string(i) + ".npy")).string(),
              s.normals[i].permute({1, 2, 0}).contiguous());  // (H,W,3) float32
  }
  auto scene = data::import_transforms_json((root / "capture").string(), (root / "scene").string(), o);
  CHECK_THAT(scene.depth_source, FLAT_CONTAINS("png files from "));
  CHECK_THAT(scene.depth_source, FLAT_CONTAINS("0.001 m per PNG unit"));
  CHECK_THAT(scene.normals_source, FLAT_CONTAINS("npy files from "));
  CHECK_THAT(scene.normals_source, FLAT_CONTAINS(", opencv"));
  auto f = load_all((root / "scene").string());
  CHECK(torch::allclose(f.depth, units * unit * 2.0, 1e-6, 1e-6));   // integer units -> metres -> metric scale
  CHECK((f.depth - s.depth * 2.0).abs().max().item<float>() <= 2.0 * 0.5 * unit + 1e-5);
  CHECK(torch::allclose(f.normals, s.normals, 1e-6, 1e-6));

  // 16-bit PNG depth without a scale, and png16 asked for without one.
  auto again = o;
  again.geometry.depth_png_scale = 0;
  CHECK_THAT(error_of([&] { data::import_transforms_json((root / "capture").string(), (root / "s2").string(), again); }),
             FLAT_CONTAINS("f0.png: 16-bit PNG depth needs --depth-png-scale"));
  again.geometry.depth_format = "png16";
  CHECK_THAT(error_of([&] { data::import_transforms_json((root / "capture").string(), (root / "s2").string(), again); }),
             FLAT_CONTAINS("--depth-format png16 needs --depth-png-scale"));
  CHECK_FALSE(fs::exists(root / "s2"));
}

TEST_CASE("geometry maps follow a resized image with nearest samples (EXR depth, (3,H,W) float16 NPY normals)",
          "[data][geometry_maps]") {
  if (!image_io_available() || !exr_available()) FLAT_SKIP("this build has no OpenImageIO: EXR depth");
  auto s = room();
  const fs::path root = write_transforms("geo_resize", s);
  auto o = with_map_folders(root, 1.5);
  o.max_size = kW / 2;  // 16x12 -> 8x6
  for (int64_t i = 0; i < kFrames; ++i) {
    data::write_depth((root / "depth" / ("f" + std::to_string(i) + ".exr")).string(), s.depth[i]);
    write_npy((root / "normals" / ("f" + std::to_string(i) + ".npy")).string(), s.normals[i].to(at::kHalf));
  }
  auto scene = data::import_transforms_json((root / "capture").string(), (root / "scene").string(), o);
  REQUIRE(scene.height == kH / 2);
  REQUIRE(scene.width == kW / 2);
  CHECK_THAT(scene.depth_source, FLAT_CONTAINS("exr files from "));
  auto f = load_all((root / "scene").string());
  // Halving with nearest takes every second pixel (odd rows and columns): no depth is averaged.
  auto odd = [](const at::Tensor& t) { return t.slice(2, 1, kH, 2).slice(3, 1, kW, 2); };
  CHECK(torch::allclose(f.depth, odd(s.depth) * 1.5, 1e-6, 1e-6));
  auto n16 = s.normals.to(at::kHalf).to(at::kFloat);
  CHECK(torch::allclose(f.normals, odd(n16 / n16.norm(2, 1, true)), 1e-5, 1e-5));
}

TEST_CASE("geometry maps are undistorted with the image's remap, sampled nearest", "[data][geometry_maps]") {
  if (!image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the capture is written as PNG");
  auto s = room();
  const double k1 = 0.3;
  const fs::path root = write_transforms("geo_distort", s, k1);
  fs::create_directories(root / "depth");
  for (int64_t i = 0; i < kFrames; ++i)
    write_npy((root / "depth" / ("f" + std::to_string(i) + ".npy")).string(), s.depth[i]);  // (1,H,W)
  data::ImportOptions o;
  o.geometry.depth_dir = (root / "depth").string();
  data::import_transforms_json((root / "capture").string(), (root / "scene").string(), o);
  auto f = load_all((root / "scene").string(), true, false);
  // Independent nearest remap: output pixel (u,v) takes the source pixel holding its distorted position.
  const double fx = s.cameras.intrinsics[0][0].item<double>() * kW, fy = s.cameras.intrinsics[0][1].item<double>() * kH;
  const double cx = s.cameras.intrinsics[0][2].item<double>() * kW, cy = s.cameras.intrinsics[0][3].item<double>() * kH;
  int64_t total = 0, same = 0, moved = 0, outside = 0;
  for (int64_t i = 0; i < kFrames; ++i)
    for (int64_t v = 0; v < kH; ++v)
      for (int64_t u = 0; u < kW; ++u) {
        const double x = (u + 0.5 - cx) / fx, y = (v + 0.5 - cy) / fy, r2 = x * x + y * y;
        const double xs = x * (1 + k1 * r2) * fx + cx, ys = y * (1 + k1 * r2) * fy + cy;
        const int64_t su = int64_t(std::floor(xs)), sv = int64_t(std::floor(ys));
        const bool in = su >= 0 && sv >= 0 && su < kW && sv < kH;
        const float want = in ? s.depth[i][0][sv][su].item<float>() : 0.0f;  // outside: unknown
        ++total;
        same += f.depth[i][0][v][u].item<float>() == want;
        moved += in && (su != u || sv != v);
        outside += !in;
      }
  INFO(same << " of " << total << " pixels equal their nearest source pixel; " << moved << " moved, " << outside
            << " outside");
  // The distortion moves pixels and pushes some outside (measured: 48 moved, 128 outside of 768): the
  // result is no plain copy, so the test has teeth.
  CHECK(moved > 0);
  CHECK(moved + outside > total / 10);
  CHECK(same >= total - total / 100);    // float intrinsics may tip a pixel at a border
}

TEST_CASE("geometry maps: every defect fails naming its file or frame", "[data][geometry_maps]") {
  if (!image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the clip is written as PNG");
  auto s = room();
  const fs::path root = write_re10k("geo_errors", s);
  auto depth_dir = [&](const std::string& name, const std::function<void(int64_t, const fs::path&)>& write) {
    fs::create_directories(root / name);
    for (int64_t i = 0; i < kFrames; ++i) write(i, root / name / timestamp(i));
    return (root / name).string();
  };
  auto import = [&](const data::GeometryOptions& g) {
    data::ImportOptions o;
    o.geometry = g;
    return error_of([&] {
      data::import_re10k((root / "cams.txt").string(), (root / "frames").string(), (root / "out").string(), o);
    });
  };
  const std::string bad = timestamp(2);  // the frame whose map is broken

  SECTION("a map of the wrong size") {
    data::GeometryOptions g;
    g.depth_dir = depth_dir("d", [&](int64_t i, const fs::path& p) {
      write_npy(p.string() + ".npy", i == 2 ? at::ones({kH + 1, kW}) : s.depth[i][0]);
    });
    const std::string msg = import(g);
    CHECK_THAT(msg, FLAT_CONTAINS(bad + ".npy: map is 16x13 but its frame's image"));
    CHECK_THAT(msg, FLAT_CONTAINS(bad + ".png is 16x12"));
  }
  SECTION("a NaN in a depth map") {
    data::GeometryOptions g;
    g.depth_dir = depth_dir("d", [&](int64_t i, const fs::path& p) {
      auto d = s.depth[i][0].clone();
      if (i == 2) d[3][5] = std::nanf("");
      write_npy(p.string() + ".npy", d);
    });
    CHECK_THAT(import(g), FLAT_CONTAINS(bad + ".npy: 1 pixels hold NaN or Inf (first at (x=5, y=3))"));
  }
  SECTION("negative depth") {
    data::GeometryOptions g;
    g.depth_dir = depth_dir("d", [&](int64_t i, const fs::path& p) {
      write_npy(p.string() + ".npy", i == 2 ? -s.depth[i][0] : s.depth[i][0]);
    });
    CHECK_THAT(import(g), FLAT_CONTAINS(bad + ".npy: " + std::to_string(kH * kW) + " depth values are negative"));
  }
  SECTION("normals that are not unit vectors") {
    data::GeometryOptions g;
    g.normals_dir = depth_dir("n", [&](int64_t i, const fs::path& p) {
      write_npy(p.string() + ".npy", i == 2 ? s.normals[i] * 0.8 : s.normals[i]);
    });
    CHECK_THAT(import(g), FLAT_CONTAINS(bad + ".npy: " + std::to_string(kH * kW) +
                                        " of " + std::to_string(kH * kW) + " nonzero normals are not of unit length"));
  }
  SECTION("OpenGL normals read as OpenCV, and OpenCV normals read as OpenGL") {
    data::GeometryOptions g;
    g.normals_dir = depth_dir("n", [&](int64_t i, const fs::path& p) {
      write_normals_png(p.string() + ".png", flip_yz(s.normals[i]));
    });
    std::string msg = import(g);
    CHECK_THAT(msg, FLAT_CONTAINS(timestamp(0) + ".png: "));
    CHECK_THAT(msg, FLAT_CONTAINS("known normals face away from the camera"));
    CHECK_THAT(msg, FLAT_CONTAINS("try --normals-convention opengl"));
    g.normals_dir = depth_dir("n2", [&](int64_t i, const fs::path& p) { write_npy(p.string() + ".npy", s.normals[i]); });
    g.normals_convention = "opengl";
    msg = import(g);
    CHECK_THAT(msg, FLAT_CONTAINS(timestamp(0) + ".npy: "));
    CHECK_THAT(msg, FLAT_CONTAINS("try --normals-convention opencv"));
  }
  SECTION("a few away-facing normals are kept as they are") {
    data::GeometryOptions g;
    auto flipped = s.normals.clone();
    flipped[1].narrow(1, 0, 2).neg_();  // 2 of 12 rows of frame 1 point away
    g.normals_dir = depth_dir("n", [&](int64_t i, const fs::path& p) { write_npy(p.string() + ".npy", flipped[i]); });
    CHECK(import(g) == "(no error)");
    auto f = load_all((root / "out").string(), false, true);
    CHECK(torch::allclose(f.normals, flipped, 1e-6, 1e-6));
    auto c = data::count_away_facing(f.normals[1], s.cameras.intrinsics[1]);
    CHECK(c.known == kH * kW);
    CHECK(c.away == 2 * kW);
    CHECK(data::count_away_facing(f.normals[0], s.cameras.intrinsics[0]).away == 0);
  }
  SECTION("a missing map for one frame") {
    data::GeometryOptions g;
    g.depth_dir = depth_dir("d", [&](int64_t i, const fs::path& p) {
      if (i != 1) write_npy(p.string() + ".npy", s.depth[i][0]);
    });
    const std::string msg = import(g);
    CHECK_THAT(msg, FLAT_CONTAINS("--depth " + g.depth_dir + ": no depth map for frame 1 (image "));
    CHECK_THAT(msg, FLAT_CONTAINS(timestamp(1) + ".png): expected " + timestamp(1) + ".exr, " + timestamp(1) + ".npy or " +
                                  timestamp(1) + ".png in "));
  }
  SECTION("an 8-bit PNG depth map") {
    data::GeometryOptions g;
    g.depth_png_scale = 0.01;
    g.depth_dir = depth_dir("d", [&](int64_t, const fs::path& p) {
      write_image(p.string() + ".png", at::full({1, kH, kW}, 0.5f));
    });
    CHECK_THAT(import(g), FLAT_CONTAINS(timestamp(0) + ".png: 8-bit PNG: too few levels for depth"));
  }
  SECTION("a Fortran-order NPY map") {
    data::GeometryOptions g;
    g.depth_dir = depth_dir("d", [&](int64_t i, const fs::path& p) { write_npy(p.string() + ".npy", s.depth[i][0]); });
    // Same bytes, header flag set: numpy.asfortranarray(...) saved.
    const fs::path file = root / "d" / (timestamp(0) + ".npy");
    std::string bytes = test::read_file(file);
    bytes.replace(bytes.find("False"), 5, "True ");
    std::ofstream(file, std::ios::binary | std::ios::trunc) << bytes;
    CHECK_THAT(import(g), FLAT_CONTAINS(timestamp(0) + ".npy: .npy array of shape (12,16) is in Fortran"));
  }
  SECTION("an integer NPY map") {
    data::GeometryOptions g;
    g.depth_dir = depth_dir("d", [&](int64_t i, const fs::path& p) {
      write_npy(p.string() + ".npy", (s.depth[i][0] * 1000).to(at::kInt));
    });
    CHECK_THAT(import(g), FLAT_CONTAINS(timestamp(0) + ".npy: .npy dtype Int is not supported for depth"));
  }
  // A failed import leaves nothing at the output.
  if (!fs::exists(root / "out" / "scene.json")) CHECK_FALSE(fs::exists(root / "out"));
}
