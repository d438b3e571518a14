// Importers: transforms.json (axis change, distortion, fox), RealEstate10K.
#include <filesystem>
#include <fstream>
#include <iomanip>

#include <nlohmann/json.hpp>

#include "flat/camera/cameras.h"
#include "flat/core/error.h"
#include "flat/data/camera_checks.h"
#include "flat/data/frame_io.h"
#include "flat/data/importers.h"
#include "flat/data/scene_frames.h"
#include "data/import_common.h"
#include "flat/data/synthetic_scene.h"
#include "flat/data/undistort.h"
#include "data_test_dirs.h"
#include "flat/core/image_io.h"
#include "test_support.h"

using namespace flat;
namespace fs = std::filesystem;

namespace {

// The data tests use tiny tensors, where intra-op threads only add overhead (and
// spin-wait on a loaded 2-core machine: 20 s instead of 3 s): one thread for the
// whole flat_test_data executable.
const bool kSingleThread = (at::set_num_threads(1), true);

data::SynthScene tiny(const std::string& family, const std::string& motion) {
  data::SynthOptions o;
  o.family = family;
  o.motion = motion;
  o.frames = 6;
  o.height = 12;
  o.width = 16;
  o.seed = 5;
  return data::render_synthetic_scene(o);
}

// Inverse of the radial-tangential model by fixed-point iteration (the usual
// undistortPoints scheme), independent of the importer's forward mapping.
std::pair<double, double> undistort_point(double xd, double yd, const data::Distortion& d) {
  double x = xd, y = yd;
  for (int i = 0; i < 50; ++i) {
    double r2 = x * x + y * y, radial = 1 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3));
    double dx = 2 * d.p1 * x * y + d.p2 * (r2 + 2 * x * x), dy = d.p1 * (r2 + 2 * y * y) + 2 * d.p2 * x * y;
    x = (xd - dx) / radial;
    y = (yd - dy) / radial;
  }
  return {x, y};
}

}  // namespace

TEST_CASE("undistortion maps a distorted pattern back to the pinhole pattern", "[data][import]") {
  const int64_t H = 60, W = 80;
  const double fx = 70, fy = 72, cx = 41, cy = 29.5;
  data::Distortion d{0.08, -0.05, 0.0, 0.002, -0.001};
  auto pattern = [](double x, double y) { return 0.5 + 0.4 * std::sin(3 * x + 1) * std::cos(2 * y); };
  // Distorted image: each pixel shows the pattern at its undistorted position.
  auto img = torch::zeros({1, H, W}, torch::kDouble);
  auto acc = img.accessor<double, 3>();
  for (int64_t v = 0; v < H; ++v)
    for (int64_t u = 0; u < W; ++u) {
      auto [x, y] = undistort_point((u + 0.5 - cx) / fx, (v + 0.5 - cy) / fy, d);
      acc[0][v][u] = pattern(x, y);
    }
  auto out = data::undistort_image(img, fx, fy, cx, cy, d);
  auto expect = torch::zeros_like(img);
  auto e = expect.accessor<double, 3>();
  for (int64_t v = 0; v < H; ++v)
    for (int64_t u = 0; u < W; ++u) e[0][v][u] = pattern((u + 0.5 - cx) / fx, (v + 0.5 - cy) / fy);
  auto inner = [&](const torch::Tensor& t) { return t.slice(1, 6, H - 6).slice(2, 6, W - 6); };
  double err = (inner(out) - inner(expect)).abs().max().item<double>();
  INFO("max error " << err);
  CHECK(err < 2e-3);
  // Without the undistortion the images differ clearly (the test has teeth).
  CHECK((inner(img) - inner(expect)).abs().max().item<double>() > 50 * err);
}

TEST_CASE("transforms.json import converts OpenGL camera axes to OpenCV", "[data][import]") {
  if (!flat::image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the capture is written as PNG");
  auto root = test::fresh_dir("import_transforms");
  auto s = tiny("object", "orbit");
  // Write the scene as a NeRF capture: OpenGL c2w (negated y and z columns), pixel focal lengths.
  nlohmann::json doc;
  const double W = 16, H = 12;
  doc["w"] = W;
  doc["h"] = H;
  doc["fl_x"] = s.cameras.intrinsics[0][0].item<double>() * W;
  doc["fl_y"] = s.cameras.intrinsics[0][1].item<double>() * H;
  doc["cx"] = 0.5 * W;
  doc["cy"] = 0.5 * H;
  fs::create_directories(root / "capture" / "images");
  for (int64_t i = 5; i >= 0; --i) {  // out of order on purpose: the importer sorts by file name
    auto m = s.cameras.c2w[i].to(torch::kDouble).clone();
    m.select(1, 1).slice(0, 0, 3).neg_();
    m.select(1, 2).slice(0, 0, 3).neg_();
    nlohmann::json rows = nlohmann::json::array();
    for (int r = 0; r < 4; ++r) rows.push_back({m[r][0].item<double>(), m[r][1].item<double>(), m[r][2].item<double>(), m[r][3].item<double>()});
    std::string file = "images/f" + std::to_string(i) + ".png";
    data::write_rgb((root / "capture" / file).string(), s.images[i]);
    doc["frames"].push_back({{"file_path", file}, {"transform_matrix", rows}});
  }
  std::ofstream(root / "capture" / "transforms.json") << doc.dump();
  data::ImportOptions o;
  o.metric_scale = 2.0;
  auto scene = data::import_transforms_json((root / "capture").string(), (root / "scene").string(), o);
  REQUIRE(scene.size() == 6);
  auto cams = scene.cameras();
  auto want = s.cameras.c2w.clone();
  want.select(2, 3).slice(1, 0, 3).mul_(2.0);
  CHECK(torch::allclose(cams.c2w, want, 1e-5, 1e-5));
  CHECK(torch::allclose(cams.intrinsics, s.cameras.intrinsics, 1e-5, 1e-5));
  auto f = data::load_frames(data::read_scene((root / "scene").string()), {3}, false, false);
  CHECK((f.images[0] - s.images[3]).abs().max().item<float>() < 1.0f / 255);
}

TEST_CASE("RealEstate10K import inverts world-to-camera and scales translations", "[data][import]") {
  if (!flat::image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the capture is written as PNG");
  auto root = test::fresh_dir("import_re10k");
  auto s = tiny("room", "pan");
  fs::create_directories(root / "frames");
  {
    std::ofstream txt(root / "cams.txt");
    txt << "https://www.youtube.com/watch?v=xxxxxxxxxxx\n" << std::setprecision(17);
    auto w2c = camera::world_to_camera(s.cameras.c2w).to(torch::kDouble);
    for (int64_t i = 0; i < 6; ++i) {
      const int64_t ts = 1000000 + 33366 * i;
      txt << ts;
      for (int k = 0; k < 4; ++k) txt << " " << s.cameras.intrinsics[i][k].item<double>();
      txt << " 0 0";
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 4; ++c) txt << " " << w2c[i][r][c].item<double>();
      txt << "\n";
      data::write_rgb((root / "frames" / (std::to_string(ts) + ".png")).string(), s.images[i]);
    }
  }
  data::ImportOptions o;
  o.metric_scale = 0.5;
  o.stride = 2;
  auto scene = data::import_re10k((root / "cams.txt").string(), (root / "frames").string(), (root / "scene").string(), o);
  REQUIRE(scene.size() == 3);
  auto want = s.cameras.c2w.index_select(0, torch::tensor({0, 2, 4})).clone();
  want.select(2, 3).slice(1, 0, 3).mul_(0.5);
  CHECK(torch::allclose(scene.cameras().c2w, want, 1e-5, 1e-5));
  CHECK(scene.frames[1].timestamp == Approx(1000000 + 2 * 33366));
  auto f = data::load_frames(scene, {2}, false, false);
  CHECK((f.images[0] - s.images[4]).abs().max().item<float>() < 1.0f / 255);

  std::ofstream(root / "bad.txt") << "12345 0.5 0.5\n";
  REQUIRE_THROWS_WITH(data::import_re10k((root / "bad.txt").string(), (root / "frames").string(),
                                         (root / "bad").string(), o),
                      FLAT_CONTAINS("bad.txt: line 1: expected a timestamp and 18 numbers"));
}

TEST_CASE("principal-axes focus finds the orbit centre of synthetic cameras", "[data][import]") {
  auto s = tiny("object", "orbit");
  auto f = data::principal_axes_focus(s.cameras);
  CHECK(f.rms_distance < 1e-4 * f.mean_camera_distance);
  CHECK(f.in_front == 1.0);
}

TEST_CASE("fox imports; its optical axes pass near a common point in front of the cameras", "[data][import][fox]") {
  const fs::path fox = fs::path(FLAT_SHARED_DIR) / "data" / "fox";
  if (!fs::exists(fox / "transforms.json")) FLAT_SKIP("shared/data/fox not found");
  if (!flat::image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the fox capture's JPEGs cannot be read");
  auto out = test::fresh_dir("import_fox") / "fox";
  data::ImportOptions o;
  o.max_size = 160;
  o.stride = 6;            // 50 of the 67 listed images exist; every 6th: 9 frames
  o.skip_missing = true;
  auto scene = data::import_transforms_json(fox.string(), out.string(), o);
  CHECK(scene.size() == 9);
  CHECK(scene.height == 160);
  CHECK(scene.width == 90);
  CHECK(scene.frames[0].intrinsics[0].item<double>() == Approx(1375.52 / 1080).epsilon(1e-5));
  auto back = data::read_scene(out.string());
  auto f = data::principal_axes_focus(back.cameras());
  std::cout << "fox: optical axes pass within RMS " << f.rms_distance << " of a point at mean distance "
            << f.mean_camera_distance << " (ratio " << f.rms_distance / f.mean_camera_distance << "), "
            << 100 * f.in_front << "% in front\n";
  // A handheld capture: the axes aim roughly at the fox (RMS ~14% of the distance).
  CHECK(f.rms_distance < 0.2 * f.mean_camera_distance);
  CHECK(f.in_front == 1.0);
  // Taking the camera x axis as the optical axis (a wrong convention) scatters the axes.
  auto sideways = back.cameras();
  auto R = torch::tensor({0.0, 0.0, 1.0, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0}, torch::kFloat).view({3, 3});
  auto rot = sideways.c2w.slice(1, 0, 3).slice(2, 0, 3);
  rot.copy_(torch::matmul(rot.clone(), R));  // new z = old x
  auto g = data::principal_axes_focus(sideways);
  CHECK(g.rms_distance / g.mean_camera_distance > 2.5 * f.rms_distance / f.mean_camera_distance);
  // Without the axis change (OpenGL z taken as forward) the point would be behind the cameras.
  auto wrong = back.cameras();
  wrong.c2w.select(2, 2).slice(1, 0, 3).neg_();
  wrong.c2w.select(2, 1).slice(1, 0, 3).neg_();
  CHECK(data::principal_axes_focus(wrong).in_front == 0.0);
  auto img = data::load_frames(back, {0}, false, false).images;
  CHECK(img.sizes() == torch::IntArrayRef({1, 3, 160, 90}));
}

TEST_CASE("an imported scene is named after its output folder, with or without a trailing slash", "[data][import]") {
  CHECK(flat::data::detail::default_scene_name("out/scene") == "scene");
  CHECK(flat::data::detail::default_scene_name("out/scene/") == "scene");
  CHECK(flat::data::detail::default_scene_name("out/scene//") == "scene");
  CHECK(flat::data::detail::default_scene_name("scene") == "scene");
}
