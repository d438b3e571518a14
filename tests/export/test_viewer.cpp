// Viewer folder: its files, its refusal to replace foreign folders, and a
// headless-chromium screenshot of a camera compared with our rasterizer's
// render of the same camera (the page's projection and axes conventions).
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include "flat/camera/camera_json.h"
#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/export/mesh_files.h"
#include "flat/export/triangle_glb.h"
#include "flat/export/viewer.h"
#include "flat/render/rasterize.h"
#include "support/process.h"
#include "test_support.h"

using flat::exporter::default_three_js_dir;
using flat::exporter::viewer_available;
using flat::exporter::write_viewer;
namespace fs = std::filesystem;

namespace {

std::string decode_base64(const std::string& text) {
  auto value = [](char c) -> int {
    if (c >= 'A' && c <= 'Z') return c - 'A';
    if (c >= 'a' && c <= 'z') return c - 'a' + 26;
    if (c >= '0' && c <= '9') return c - '0' + 52;
    return c == '+' ? 62 : c == '/' ? 63 : -1;
  };
  std::string out;
  uint32_t acc = 0;
  int bits = 0;
  for (char c : text) {
    const int v = value(c);
    if (v < 0) break;  // '=' padding
    acc = (acc << 6) | uint32_t(v);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out += char((acc >> bits) & 0xFF);
    }
  }
  return out;
}

// The string literal of `window.NAME = "...";` in a script.
std::string script_string(const std::string& script, const std::string& name) {
  const std::string key = "window." + name + " = \"";
  const size_t a = script.find(key);
  REQUIRE(a != std::string::npos);
  const size_t b = script.find('"', a + key.size());
  REQUIRE(b != std::string::npos);
  return script.substr(a + key.size(), b - a - key.size());
}

flat::camera::CameraSet one_camera(const torch::Tensor& intrinsics, const torch::Tensor& c2w, int64_t w, int64_t h) {
  flat::camera::CameraSet set;
  set.cameras.intrinsics = intrinsics.reshape({1, 4}).to(torch::kFloat);
  set.cameras.c2w = c2w.reshape({1, 4, 4}).to(torch::kFloat);
  set.width = w;
  set.height = h;
  return set;
}

torch::Tensor rotation(double ax, double ay, double az) {
  const auto f64 = torch::TensorOptions().dtype(torch::kDouble);
  auto rx = torch::tensor({{1.0, 0.0, 0.0}, {0.0, std::cos(ax), -std::sin(ax)}, {0.0, std::sin(ax), std::cos(ax)}}, f64);
  auto ry = torch::tensor({{std::cos(ay), 0.0, std::sin(ay)}, {0.0, 1.0, 0.0}, {-std::sin(ay), 0.0, std::cos(ay)}}, f64);
  auto rz = torch::tensor({{std::cos(az), -std::sin(az), 0.0}, {std::sin(az), std::cos(az), 0.0}, {0.0, 0.0, 1.0}}, f64);
  return ry.matmul(rx).matmul(rz);
}

torch::Tensor c2w_of(const torch::Tensor& r, const torch::Tensor& t) {
  auto m = torch::eye(4, torch::kDouble);
  m.narrow(0, 0, 3).narrow(1, 0, 3).copy_(r);  // copy_ converts any dtype
  m.narrow(0, 0, 3).select(1, 3).copy_(t);
  return m;
}

}  // namespace

TEST_CASE("viewer: folder holds the page, three.js, the GLB and the cameras", "[export][viewer]") {
  const std::string three = default_three_js_dir();
  if (!viewer_available(three)) FLAT_SKIP("three.js r111 not found in " + three + " (Debian package libjs-three)");
  auto dir = flat::test::scratch_dir("viewer_files");
  // Any GLB-looking bytes do: the page is not run here. All 256 byte values
  // and a length that needs base64 padding.
  std::string glb = "glTF";
  for (int i = 0; i < 300; ++i) glb += char(i & 0xFF);
  const auto glb_path = (dir / "scene.glb").string();
  std::ofstream(glb_path, std::ios::binary) << glb;
  auto cams = one_camera(torch::tensor({0.8, 1.1, 0.45, 0.55}), c2w_of(rotation(0.1, 0.2, 0.3), torch::tensor({1.0, 2.0, 3.0})),
                         64, 48);
  const auto folder = (dir / "viewer").string();
  write_viewer(folder, glb_path, cams, three);
  for (const char* f : {"index.html", "three.min.js", "OrbitControls.js", "GLTFLoader.js", "scene_glb.js", "cameras.js"})
    CHECK(fs::is_regular_file(fs::path(folder) / f));
  CHECK(flat::test::read_file(folder + "/three.min.js") == flat::test::read_file(three + "/three.min.js"));
  CHECK(decode_base64(script_string(flat::test::read_file(folder + "/scene_glb.js"), "FLAT_SCENE_GLB")) == glb);
  std::string cams_js = flat::test::read_file(folder + "/cameras.js");
  const size_t eq = cams_js.find("window.FLAT_CAMERAS = ");
  REQUIRE(eq != std::string::npos);
  cams_js = cams_js.substr(eq + 22);
  cams_js = cams_js.substr(0, cams_js.rfind(';'));
  const auto doc = nlohmann::json::parse(cams_js);
  REQUIRE(doc["cameras"].size() == 1);
  CHECK(doc["cameras"][0]["width"] == 64);
  CHECK(doc["cameras"][0]["intrinsics"][2].get<double>() == Approx(0.45));
  CHECK(doc["cameras"][0]["c2w"][2][3].get<double>() == Approx(3.0));
  const std::string page = flat::test::read_file(folder + "/index.html");
  for (const char* s : {"three.min.js", "OrbitControls.js", "GLTFLoader.js", "scene_glb.js", "cameras.js"})
    CHECK(page.find(std::string("<script src=\"") + s + "\"></script>") != std::string::npos);

  // Writing again replaces our own folder (no staging folder left behind) ...
  std::ofstream(folder + "/stale.txt") << "old";
  write_viewer(folder, glb_path, cams, three);
  CHECK(!fs::exists(folder + "/stale.txt"));
  int entries = 0;
  for (const auto& e : fs::directory_iterator(dir)) entries += e.path().filename().string().find("viewer") == 0;
  CHECK(entries == 1);
  // ... but never someone else's folder.
  const auto foreign = (dir / "photos").string();
  fs::create_directories(foreign);
  std::ofstream(foreign + "/holiday.jpg") << "jpeg";
  REQUIRE_THROWS_WITH(write_viewer(foreign, glb_path, cams, three), FLAT_CONTAINS("photos: exists and is not a FLAT viewer"));
  CHECK(fs::exists(foreign + "/holiday.jpg"));
  REQUIRE_THROWS_WITH(write_viewer((dir / "v2").string(), glb_path, cams, (dir / "no_three").string()),
                      FLAT_CONTAINS("libjs-three"));
  REQUIRE_THROWS_WITH(write_viewer((dir / "v3").string(), (dir / "none.glb").string(), cams, three),
                      FLAT_CONTAINS("none.glb"));
  CHECK(!fs::exists(dir / "v2"));
  CHECK(!fs::exists(dir / "v3"));
}

namespace {

// Opaque, sharp-edged triangles seen by an off-centre camera with a
// non-trivial pose, as a GLB in a viewer folder whose start camera has the
// image size cam_w x cam_h.
struct ShotScene {
  torch::Tensor vertices, colors, opacities, sigmas, intrinsics, c2w;
  std::string folder;
};

ShotScene shot_scene(const fs::path& dir, int64_t cam_w, int64_t cam_h) {
  const int64_t n = 14;
  ShotScene sc;
  sc.intrinsics = torch::tensor({0.85, 1.05, 0.44, 0.57});
  const auto r = rotation(-0.25, 0.35, 0.12);
  const auto t = torch::tensor({0.4, -0.3, 0.2}, torch::kDouble);
  auto gen = at::make_generator<at::CPUGeneratorImpl>(17);
  auto uni = [&](std::vector<int64_t> shape, double lo, double hi) {
    return at::rand(shape, gen, torch::TensorOptions().dtype(torch::kDouble)) * (hi - lo) + lo;
  };
  // Centres at pixel positions (u, v) in [0.1, 0.9] of the image and depth z.
  const auto z = uni({n}, 3.0, 6.0), u = uni({n}, 0.1, 0.9), v = uni({n}, 0.1, 0.9);
  const auto centre = torch::stack({(u - 0.44) / 0.85 * z, (v - 0.57) / 1.05 * z, z}, 1);
  const auto cam_pts = centre.unsqueeze(1) + uni({n, 3, 3}, -0.45, 0.45) * (z / 4).view({n, 1, 1});
  sc.vertices = (cam_pts.matmul(r.t()) + t).to(torch::kFloat);  // world = R X + t
  // Colours far from the magenta background (green channel >= 0.5).
  sc.colors = torch::stack({uni({n}, 0.0, 0.6), uni({n}, 0.5, 1.0), uni({n}, 0.0, 0.6)}, 1).to(torch::kFloat);
  sc.opacities = torch::ones({n});
  sc.sigmas = torch::full({n}, 0.01);  // window ~1 on the whole triangle
  sc.c2w = c2w_of(r, t);
  const auto glb = (dir / "scene.glb").string();
  flat::exporter::write_triangle_glb(glb, {sc.vertices, sc.colors, sc.opacities, sc.sigmas});
  sc.folder = (dir / "viewer").string();
  write_viewer(sc.folder, glb, one_camera(sc.intrinsics, sc.c2w, cam_w, cam_h), default_three_js_dir());
  return sc;
}

// The rasterizer's view of the scene at w x h (the intrinsics are normalised: any size).
flat::render::RenderOutput raster_view(const ShotScene& sc, int64_t w, int64_t h) {
  flat::render::RasterSettings settings;
  settings.eps = 0.0;  // support = the triangle, as the viewer draws it
  settings.background = {1.0, 0.0, 1.0};
  auto cams = one_camera(sc.intrinsics, sc.c2w, w, h);
  return flat::render::rasterize(sc.vertices, sc.colors, sc.opacities, sc.sigmas, cams.cameras, h, w, settings);
}

// Headless chromium's screenshot of index.html?query in a win_w x win_h window (RGB, [0,1]).
torch::Tensor screenshot(const std::string& chromium, const fs::path& dir, const ShotScene& sc, const std::string& query,
                         int64_t win_w, int64_t win_h, const std::string& name) {
  const auto png = (dir / (name + ".png")).string();
  const auto log = png + ".log";
  const std::string url = "file://" + fs::absolute(sc.folder).string() + "/index.html?" + query + "&bg=ff00ff";
  const int rc = flat::test::run_program(
      {chromium, "--headless=new", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
       "--enable-unsafe-swiftshader", "--disable-dev-shm-usage", "--hide-scrollbars", "--no-first-run",
       "--user-data-dir=" + (dir / "chromium-profile").string(),
       "--window-size=" + std::to_string(win_w) + "," + std::to_string(win_h), "--virtual-time-budget=20000",
       "--screenshot=" + png, url},
      log, 180);
  INFO("chromium log: " << flat::test::read_file(log));
  REQUIRE(rc == 0);
  REQUIRE(fs::exists(png));
  const auto img = flat::read_image(png);
  REQUIRE(img.size(1) == win_h);
  REQUIRE(img.size(2) == win_w);
  return img.narrow(0, 0, 3);
}

// IoU of the screenshot's non-background pixels with the rasterizer's alpha > 0.5,
// and the mean colour difference where both see a triangle.
std::pair<double, double> compare(const torch::Tensor& rgb, const flat::render::RenderOutput& out) {
  const auto alpha_mask = out.alpha[0][0] > 0.5;
  const auto bg = torch::tensor({1.0f, 0.0f, 1.0f}).view({3, 1, 1});
  const auto shot_mask = (rgb - bg).abs().amax(0) > 0.25;
  const double iou = (shot_mask & alpha_mask).sum().item<double>() / (shot_mask | alpha_mask).sum().item<double>();
  const auto both = (shot_mask & alpha_mask).unsqueeze(0).expand_as(rgb);
  const double colour_err = (rgb - out.rgb[0]).abs().masked_select(both).mean().item<double>();
  return {iou, colour_err};
}

// The screenshot `rgb` shows the rasterizer's `view`: IoU >= 0.9 of their
// masks and a mean colour difference below 0.05 (printed, with `what`).
void check_screenshot_matches(const torch::Tensor& rgb, const flat::render::RenderOutput& view,
                              const std::string& what) {
  const auto [iou, colour_err] = compare(rgb, view);
  std::printf("viewer screenshot, %s: IoU %.4f with the rasterizer's alpha > 0.5, mean |colour difference| %.4f\n",
              what.c_str(), iou, colour_err);
  CHECK(iou >= 0.9);
  CHECK(colour_err < 0.05);
}

// Why a screenshot cannot be taken here ("" when it can). The viewer uses
// the default three.js folder.
std::string no_screenshot(std::string& chromium) {
  const std::string three = default_three_js_dir();
  chromium = flat::test::find_program("chromium");
  if (chromium.empty()) return "no chromium on PATH (Debian package chromium): viewer not checked against the rasterizer";
  if (!viewer_available(three)) return "three.js r111 not found in " + three + " (Debian package libjs-three)";
  if (!flat::exporter::glb_export_available()) return "built without tinygltf (Debian libtinygltf-dev)";
  if (!flat::image_io_available()) return "built without OpenImageIO: cannot read the screenshot";
  return "";
}

}  // namespace

TEST_CASE("viewer: a chromium screenshot of a camera matches the rasterizer's view", "[export][viewer]") {
  std::string chromium;
  if (const std::string why = no_screenshot(chromium); !why.empty()) FLAT_SKIP(why);
  auto dir = flat::test::scratch_dir("viewer_screenshot");
  // Headless chromium lays small windows out at a 500-pixel minimum width: stay above it.
  const int64_t width = 640, height = 480;
  const auto sc = shot_scene(dir, width, height);
  const auto out = raster_view(sc, width, height);
  REQUIRE((out.alpha[0][0] > 0.5).sum().item<int64_t>() > 1000);  // the scene is in view
  flat::write_image((dir / "rasterizer.png").string(), out.rgb[0]);  // to compare by eye when this fails

  // camera=0 (the start camera) and the same camera given explicitly in the URL.
  std::string explicit_camera = "c2w=";
  for (int i = 0; i < 16; ++i) {
    char num[40];
    std::snprintf(num, sizeof(num), "%s%.9g", i ? "," : "", sc.c2w.view({16})[i].item<double>());
    explicit_camera += num;
  }
  explicit_camera += "&fx=0.85&fy=1.05&cx=0.44&cy=0.57";
  int shot = 0;
  for (const std::string& query : {std::string("camera=0"), explicit_camera}) {
    const auto rgb = screenshot(chromium, dir, sc, query, width, height, "shot" + std::to_string(shot++));
    check_screenshot_matches(rgb, out, query.substr(0, 8) + "...");
  }
}

TEST_CASE("viewer: a 5:3 camera in a 4:3 window is letterboxed, not stretched", "[export][viewer]") {
  std::string chromium;
  if (const std::string why = no_screenshot(chromium); !why.empty()) FLAT_SKIP(why);
  auto dir = flat::test::scratch_dir("viewer_aspect");
  const auto sc = shot_scene(dir, 640, 384);  // 5:3 images
  // An 800x600 window: the view is 800x480, centred (60 rows above and below).
  const auto rgb = screenshot(chromium, dir, sc, "camera=0", 800, 600, "shot_4x3");
  const auto out = raster_view(sc, 800, 480);
  check_screenshot_matches(rgb.narrow(1, 60, 480), out, "5:3 camera in a 4:3 window");
  // Nothing of the scene is drawn in the bands.
  const auto bg = torch::tensor({1.0f, 0.0f, 1.0f}).view({3, 1, 1});
  CHECK((rgb.narrow(1, 0, 55) - bg).abs().amax(0).lt(0.25).sum().item<int64_t>() == 0);  // not the canvas' magenta
}

TEST_CASE("viewer: with a mesh GLB the page toggles to the opaque mesh (show=mesh)", "[export][viewer]") {
  std::string chromium;
  if (const std::string why = no_screenshot(chromium); !why.empty()) FLAT_SKIP(why);
  auto dir = flat::test::scratch_dir("viewer_mesh");
  const int64_t width = 640, height = 480;
  auto sc = shot_scene(dir, width, height);
  // The "mesh": the same triangles, shared nothing, in one cyan (the soup's
  // colours all have green >= 0.5 and differ from it).
  auto mesh = flat::primitives::mesh_from_soup({sc.vertices, sc.colors, sc.opacities, sc.sigmas});
  mesh.colors = torch::tensor({0.1f, 0.9f, 0.9f}).expand({mesh.num_vertices(), 3}).contiguous();
  const auto mesh_glb = (dir / "mesh.glb").string();
  flat::exporter::write_mesh_glb(mesh_glb, mesh);
  sc.folder = (dir / "viewer_mesh").string();
  write_viewer(sc.folder, (dir / "scene.glb").string(), one_camera(sc.intrinsics, sc.c2w, width, height),
               default_three_js_dir(), mesh_glb);
  CHECK(decode_base64(script_string(flat::test::read_file(sc.folder + "/mesh_glb.js"), "FLAT_MESH_GLB")) ==
        flat::test::read_file(mesh_glb));
  const auto soup_view = raster_view(sc, width, height);
  auto cyan = sc;
  cyan.colors = torch::tensor({0.1f, 0.9f, 0.9f}).expand({sc.vertices.size(0), 3}).contiguous();
  const auto mesh_view = raster_view(cyan, width, height);
  // The toggle button sits in the top-right corner: that corner is left out of the comparison.
  const auto hide_button = [&](torch::Tensor shot, flat::render::RenderOutput& view) {
    shot.narrow(1, 0, 48).narrow(2, width - 320, 320).copy_(torch::tensor({1.f, 0.f, 1.f}).view({3, 1, 1}));
    view.alpha.narrow(2, 0, 48).narrow(3, width - 320, 320).zero_();
    return shot;
  };
  auto soup_view_c = soup_view, mesh_view_c = mesh_view;
  soup_view_c.alpha = soup_view.alpha.clone();
  mesh_view_c.alpha = mesh_view.alpha.clone();
  const auto soup_shot = hide_button(screenshot(chromium, dir, sc, "camera=0", width, height, "soup"), soup_view_c);
  const auto mesh_shot =
      hide_button(screenshot(chromium, dir, sc, "camera=0&show=mesh", width, height, "mesh"), mesh_view_c);
  check_screenshot_matches(soup_shot, soup_view_c, "with mesh, the soup");
  check_screenshot_matches(mesh_shot, mesh_view_c, "with mesh, show=mesh");
  // The mesh shot is not the soup's: the colours differ where both draw.
  CHECK(compare(mesh_shot, soup_view_c).second > 0.1);
}
