// transforms.json (NeRF / instant-ngp / nerfstudio) -> scene folder.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "data/import_common.h"
#include "flat/camera/cameras.h"
#include "flat/core/error.h"
#include "flat/core/progress.h"
#include "flat/data/frame_io.h"
#include "flat/data/frame_resize.h"
#include "flat/data/geometry_maps.h"
#include "flat/data/importers.h"
#include "flat/data/undistort.h"

namespace flat::data {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

// Camera fields of one frame: the frame's own values override the file's.
struct FrameCamera {
  double w = 0, h = 0, fx = 0, fy = 0, cx = 0, cy = 0;
  Distortion dist;
};

double get(const json& frame, const json& doc, const char* key, double fallback, bool* found = nullptr) {
  for (const json* j : {&frame, &doc})
    if (j->contains(key) && (*j)[key].is_number()) {
      if (found) *found = true;
      return (*j)[key].get<double>();
    }
  if (found) *found = false;
  return fallback;
}

FrameCamera frame_camera(const json& f, const json& doc, int64_t image_h, int64_t image_w, const std::string& where) {
  FrameCamera c;
  c.w = get(f, doc, "w", double(image_w));
  c.h = get(f, doc, "h", double(image_h));
  bool has_fx = false, has_fy = false;
  c.fx = get(f, doc, "fl_x", 0, &has_fx);
  c.fy = get(f, doc, "fl_y", 0, &has_fy);
  if (!has_fx) {
    bool has_angle = false;
    double ax = get(f, doc, "camera_angle_x", 0, &has_angle);
    if (!has_angle) fail(where + ": no focal length ('fl_x' or 'camera_angle_x')");
    c.fx = 0.5 * c.w / std::tan(0.5 * ax);
  }
  if (!has_fy) {
    bool has_angle = false;
    double ay = get(f, doc, "camera_angle_y", 0, &has_angle);
    c.fy = has_angle ? 0.5 * c.h / std::tan(0.5 * ay) : c.fx;
  }
  c.cx = get(f, doc, "cx", 0.5 * c.w);
  c.cy = get(f, doc, "cy", 0.5 * c.h);
  c.dist.k1 = get(f, doc, "k1", 0);
  c.dist.k2 = get(f, doc, "k2", 0);
  c.dist.k3 = get(f, doc, "k3", 0);
  c.dist.p1 = get(f, doc, "p1", 0);
  c.dist.p2 = get(f, doc, "p2", 0);
  if (get(f, doc, "k4", 0) != 0) fail(where + ": 'k4' (fisheye / rational model) is not supported");
  for (const json* j : {&f, &doc})
    if (j->contains("camera_model")) {
      std::string m = (*j)["camera_model"].get<std::string>();
      if (m != "OPENCV" && m != "PINHOLE" && m != "SIMPLE_PINHOLE" && m != "SIMPLE_RADIAL" && m != "RADIAL")
        fail(where + ": camera_model '" + m + "' is not supported (OPENCV radial-tangential or pinhole)");
      break;
    }
  FLAT_CHECK(c.fx > 0 && c.fy > 0 && c.w > 0 && c.h > 0, where + ": focal lengths and image size must be positive");
  return c;
}

// The image of a frame, or "" when it does not exist and skip_missing is set.
std::string resolve_image(const fs::path& base, const std::string& file_path, const std::string& where,
                          bool skip_missing) {
  fs::path p = base / file_path;
  if (fs::exists(p) && fs::is_regular_file(p)) return p.string();
  if (!p.has_extension())  // NeRF synthetic: "./train/r_0" means r_0.png
    for (const char* ext : {".png", ".jpg", ".jpeg", ".PNG", ".JPG"})
      if (fs::exists(p.string() + ext)) return p.string() + ext;
  if (skip_missing) return "";
  fail(where + ": image '" + p.string() + "' does not exist (--skip-missing skips such frames)");
}

}  // namespace

Scene import_transforms_json(const std::string& source, const std::string& out_dir, const ImportOptions& o) {
  fs::path file = fs::is_directory(source) ? fs::path(source) / "transforms.json" : fs::path(source);
  std::ifstream in(file);
  if (!in) fail(file.string() + ": cannot open transforms file");
  json doc;
  try {
    doc = json::parse(in);
  } catch (const json::exception& e) {
    fail(file.string() + ": invalid JSON: " + e.what());
  }
  if (!doc.is_object() || !doc.contains("frames") || !doc["frames"].is_array() || doc["frames"].empty())
    fail(file.string() + ": expected an object with a non-empty 'frames' array");
  FLAT_CHECK(o.metric_scale > 0, "import: metric scale must be positive");
  FLAT_CHECK(o.stride >= 1, "import: stride must be >= 1");

  // Video order: frames sorted by file name (nerfstudio files are not always in order).
  std::vector<json> frames(doc["frames"].begin(), doc["frames"].end());
  for (size_t i = 0; i < frames.size(); ++i)
    if (!frames[i].contains("file_path") || !frames[i]["file_path"].is_string() ||
        !frames[i].contains("transform_matrix"))
      fail(file.string() + ": frames[" + std::to_string(i) + "] needs 'file_path' and 'transform_matrix'");
  std::stable_sort(frames.begin(), frames.end(), [](const json& a, const json& b) {
    return a["file_path"].get<std::string>() < b["file_path"].get<std::string>();
  });
  // Frames whose image is missing: an error, or skipped with a warning (instant-ngp's fox
  // lists 67 frames and ships 50 images).
  const fs::path base = file.parent_path();
  std::vector<json> present;
  std::vector<std::string> paths;
  int64_t missing = 0;
  for (const auto& f : frames) {
    const std::string where = file.string() + ": " + f["file_path"].get<std::string>();
    std::string path = resolve_image(base, f["file_path"].get<std::string>(), where, o.skip_missing);
    if (path.empty()) {
      ++missing;
      continue;
    }
    present.push_back(f);
    paths.push_back(path);
  }
  if (missing) spdlog::warn("{}: skipped {} frames whose image does not exist", file.string(), missing);
  std::vector<json> kept;
  std::vector<std::string> kept_paths;
  for (size_t i = 0; i < present.size(); i += size_t(o.stride)) {
    kept.push_back(present[i]);
    kept_paths.push_back(paths[i]);
  }
  if (o.max_frames > 0 && int64_t(kept.size()) > o.max_frames) kept.resize(size_t(o.max_frames));
  if (kept.empty()) fail(file.string() + ": no frames with images");
  kept_paths.resize(kept.size());
  GeometryImport geometry(o.geometry, o.metric_scale, kept_paths);  // every frame's maps found before any is written

  auto staged = detail::begin_import(out_dir, o.overwrite);
  Scene scene;
  scene.dir = staged->path();
  scene.name = o.name.empty() ? detail::default_scene_name(out_dir) : o.name;
  scene.source = "transforms.json: " + file.string();
  scene.metric_scale = o.metric_scale;
  Progress progress("import " + scene.name, int64_t(kept.size()));
  for (size_t i = 0; i < kept.size(); ++i) {
    const json& f = kept[i];
    const std::string where = file.string() + ": " + f["file_path"].get<std::string>();
    at::Tensor rgb = read_rgb(kept_paths[i]);
    const int64_t H = rgb.size(1), W = rgb.size(2);
    FrameCamera c = frame_camera(f, doc, H, W, where);
    // Intrinsics normalised by the declared size serve the actual image too
    // (e.g. DL3DV's downsampled images_4 with full-resolution intrinsics).
    if (std::abs(c.w * H - c.h * W) > 0.01 * c.w * H)
      fail(where + ": image " + std::to_string(W) + "x" + std::to_string(H) + " does not have the aspect ratio of w x h = " +
           std::to_string(int64_t(c.w)) + "x" + std::to_string(int64_t(c.h)));
    if (i == 0) std::tie(scene.height, scene.width) = detail::import_size(H, W, o.max_size);
    auto [oh, ow] = detail::import_size(H, W, o.max_size);
    if (oh != scene.height || ow != scene.width) fail(where + ": image size differs from the first frame's");
    // Shrink first (antialiased), then undistort at the output size: the distortion model
    // lives in normalised coordinates, so only the pixel intrinsics scale.
    rgb = resize_images(rgb.unsqueeze(0), oh, ow)[0];
    const double sx = double(ow) / c.w, sy = double(oh) / c.h;
    rgb = undistort_image(rgb, c.fx * sx, c.fy * sy, c.cx * sx, c.cy * sy, c.dist).clamp(0, 1);

    // OpenGL camera axes (y up, z backward) -> OpenCV (y down, z forward): negate columns 1 and 2.
    const json& m = f["transform_matrix"];
    if (!m.is_array() || m.size() < 3) fail(where + ": 'transform_matrix' must be 4x4 (or 3x4)");
    auto c2w = at::eye(4, at::kDouble);
    for (int r = 0; r < 3; ++r)
      for (int k = 0; k < 4; ++k) {
        if (!m[r].is_array() || m[r].size() != 4 || !m[r][k].is_number())
          fail(where + ": 'transform_matrix' must hold 4 numbers per row");
        c2w[r][k] = m[r][k].get<double>();
      }
    c2w.select(1, 1).narrow(0, 0, 3).neg_();
    c2w.select(1, 2).narrow(0, 0, 3).neg_();
    c2w.select(1, 3).narrow(0, 0, 3).mul_(o.metric_scale);

    SceneFrame frame;
    frame.intrinsics = at::tensor({c.fx / c.w, c.fy / c.h, c.cx / c.w, c.cy / c.h}, at::kDouble).to(at::kFloat);
    frame.c2w = detail::rigid(c2w, where + ": 'transform_matrix'");
    // Its maps resized and undistorted as the image.
    detail::add_import_frame(scene, int64_t(i), std::move(frame), rgb, geometry, H, W, c.dist);
    progress.step();
  }
  progress.finish();
  detail::finish_import(scene, geometry, *staged);
  return scene;
}

}  // namespace flat::data
