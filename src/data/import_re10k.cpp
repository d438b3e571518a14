// RealEstate10K camera file + frames folder -> scene folder.
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "data/import_common.h"
#include "flat/camera/cameras.h"
#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/progress.h"
#include "flat/data/frame_io.h"
#include "flat/data/geometry_maps.h"
#include "flat/data/importers.h"

namespace flat::data {

namespace fs = std::filesystem;

namespace {

struct Re10kLine {
  std::string timestamp;  // as written (microseconds), used to find the frame file
  double values[18];      // fx fy cx cy 0 0 and the 3x4 world-to-camera, row-major
};

std::vector<Re10kLine> parse_re10k(const std::string& path) {
  std::ifstream in(path);
  if (!in) fail(path + ": cannot open RealEstate10K camera file");
  std::vector<Re10kLine> lines;
  std::string text;
  int64_t number = 0;
  while (std::getline(in, text)) {
    ++number;
    if (text.find_first_not_of(" \t\r") == std::string::npos) continue;
    std::istringstream s(text);
    Re10kLine line;
    s >> line.timestamp;
    if (number == 1 && line.timestamp.find("://") != std::string::npos) continue;  // the video URL
    for (double& v : line.values)
      if (!(s >> v)) fail(path + ": line " + std::to_string(number) + ": expected a timestamp and 18 numbers");
    for (double v : line.values)
      if (!std::isfinite(v)) fail(path + ": line " + std::to_string(number) + ": non-finite value");
    if (line.values[0] <= 0 || line.values[1] <= 0)
      fail(path + ": line " + std::to_string(number) + ": focal lengths must be positive");
    lines.push_back(line);
  }
  if (lines.empty()) fail(path + ": no camera lines");
  return lines;
}

std::vector<std::string> match_frames(const std::vector<Re10kLine>& lines, const std::string& frames_dir,
                                      const std::string& camera_file) {
  if (!fs::is_directory(frames_dir)) fail(frames_dir + ": frames folder does not exist");
  std::vector<std::string> out;
  for (const auto& l : lines) {
    std::string found;
    for (const char* ext : {".png", ".jpg", ".jpeg"})
      if (fs::exists(fs::path(frames_dir) / (l.timestamp + ext))) {
        found = (fs::path(frames_dir) / (l.timestamp + ext)).string();
        break;
      }
    if (found.empty()) {
      out.clear();
      break;
    }
    out.push_back(found);
  }
  if (!out.empty()) return out;
  // No <timestamp>.png names: one image per camera line, in name order.
  auto images = list_images(frames_dir);
  if (images.size() != lines.size())
    fail(frames_dir + ": " + std::to_string(images.size()) + " images but " + camera_file + " has " +
         std::to_string(lines.size()) + " camera lines (and no <timestamp>.png/jpg names)");
  return images;
}

}  // namespace

Scene import_re10k(const std::string& camera_file, const std::string& frames_dir, const std::string& out_dir,
                   const ImportOptions& o) {
  FLAT_CHECK(o.metric_scale > 0, "import: metric scale must be positive");
  FLAT_CHECK(o.stride >= 1, "import: stride must be >= 1");
  auto all = parse_re10k(camera_file);
  auto files = match_frames(all, frames_dir, camera_file);
  std::vector<size_t> keep;
  for (size_t i = 0; i < all.size(); i += size_t(o.stride)) keep.push_back(i);
  if (o.max_frames > 0 && int64_t(keep.size()) > o.max_frames) keep.resize(size_t(o.max_frames));

  std::vector<std::string> kept_files;
  for (size_t i : keep) kept_files.push_back(files[i]);
  GeometryImport geometry(o.geometry, o.metric_scale, kept_files);  // every frame's maps found before any is written
  auto staged = detail::begin_import(out_dir, o.overwrite);
  Scene scene;
  scene.dir = staged->path();
  scene.name = o.name.empty() ? detail::default_scene_name(out_dir) : o.name;
  scene.source = "RealEstate10K: " + camera_file;
  scene.metric_scale = o.metric_scale;
  Progress progress("import " + scene.name, int64_t(keep.size()));
  for (size_t k = 0; k < keep.size(); ++k) {
    const Re10kLine& l = all[keep[k]];
    at::Tensor rgb = read_rgb(files[keep[k]]);
    auto [oh, ow] = detail::import_size(rgb.size(1), rgb.size(2), o.max_size);
    if (k == 0) {
      scene.height = oh;
      scene.width = ow;
    } else if (oh != scene.height || ow != scene.width) {
      fail(files[keep[k]] + ": image size differs from the first frame's");
    }
    auto w2c = at::eye(4, at::kDouble);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) w2c[r][c] = l.values[6 + 4 * r + c];
    const std::string where = camera_file + ": camera line of timestamp " + l.timestamp;
    auto c2w = camera::world_to_camera(detail::rigid(w2c, where).to(at::kDouble).unsqueeze(0))[0];  // rigid inverse
    c2w.select(1, 3).narrow(0, 0, 3).mul_(o.metric_scale);
    SceneFrame frame;
    frame.intrinsics = at::tensor({l.values[0], l.values[1], l.values[2], l.values[3]}, at::kDouble).to(at::kFloat);
    frame.c2w = detail::rigid(c2w, where);
    frame.timestamp = std::stod(l.timestamp);
    detail::add_import_frame(scene, int64_t(k), std::move(frame), rgb, geometry, rgb.size(1), rgb.size(2));
    progress.step();
  }
  progress.finish();
  detail::finish_import(scene, geometry, *staged);
  return scene;
}

}  // namespace flat::data
