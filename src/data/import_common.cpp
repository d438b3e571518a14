#include <cmath>
#include <filesystem>

#include <spdlog/spdlog.h>

#include "data/import_common.h"
#include "flat/core/error.h"
#include "flat/data/camera_checks.h"
#include "flat/data/frame_io.h"
#include "flat/data/frame_resize.h"

namespace flat::data::detail {

std::pair<int64_t, int64_t> import_size(int64_t height, int64_t width, int64_t max_size) {
  if (max_size <= 0 || std::max(height, width) <= max_size) return {height, width};
  const double s = double(max_size) / double(std::max(height, width));
  return {std::max<int64_t>(1, std::llround(height * s)), std::max<int64_t>(1, std::llround(width * s))};
}

std::string write_import_image(const Scene& scene, int64_t index, const at::Tensor& rgb) {
  // A pure resize keeps normalised intrinsics exactly (pixel centres scale with the image).
  auto out = resize_images(rgb.unsqueeze(0), scene.height, scene.width)[0].clamp(0, 1);
  std::string rel = "images/" + frame_stem(index) + rgb_extension();
  std::filesystem::create_directories(scene.path("images"));
  write_rgb(scene.path(rel), out);
  return rel;
}

at::Tensor rigid(const at::Tensor& c2w, const std::string& where) {
  auto m = c2w.to(at::kDouble).clone();
  auto [U, S, Vh] = at::linalg_svd(m.narrow(0, 0, 3).narrow(1, 0, 3));
  const double smax = S.max().item<double>(), smin = S.min().item<double>();
  if (!(smax > 0) || !(smin > 1e-3 * smax))
    fail(where + ": the pose's 3x3 rotation is degenerate (singular values " + std::to_string(S[0].item<double>()) +
         ", " + std::to_string(S[1].item<double>()) + ", " + std::to_string(S[2].item<double>()) +
         "): not a camera orientation");
  auto R = at::matmul(U, Vh);
  if (at::det(R).item<double>() < 0)
    fail(where + ": camera pose has a reflection (det R < 0): check the axis convention");
  m.narrow(0, 0, 3).narrow(1, 0, 3).copy_(R);
  m[3] = at::tensor({0.0, 0.0, 0.0, 1.0}, at::kDouble);
  return m.to(at::kFloat);
}

std::string default_scene_name(const std::string& out_dir) {
  std::filesystem::path p = std::filesystem::path(out_dir).lexically_normal();
  if (!p.has_filename()) p = p.parent_path();
  return p.filename().string();
}

std::unique_ptr<StagedDir> begin_import(const std::string& out_dir, bool overwrite) {
  std::error_code ec;
  if (std::filesystem::is_directory(out_dir, ec) && std::filesystem::is_empty(out_dir, ec))
    std::filesystem::remove(out_dir, ec);  // an empty folder holds nothing to protect
  return std::make_unique<StagedDir>(out_dir, overwrite);
}

void add_import_frame(Scene& scene, int64_t index, SceneFrame frame, const at::Tensor& rgb, GeometryImport& geometry,
                      int64_t source_height, int64_t source_width, const Distortion& distortion) {
  frame.image = write_import_image(scene, index, rgb);
  geometry.attach(scene, index, frame, source_height, source_width, distortion);
  scene.frames.push_back(std::move(frame));
}

void finish_import(Scene& scene, const GeometryImport& geometry, StagedDir& staged) {
  geometry.finish(scene);
  write_scene_json(scene);
  staged.commit();
  scene.dir = staged.target();
  if (scene.size() >= 2) {
    try {
      AxesFocus f = principal_axes_focus(scene.cameras());
      spdlog::info("{}: {} frames {}x{}; optical axes pass within RMS {:.3g} of a point at mean distance {:.3g} "
                   "({:.0f}% of cameras see it in front)",
                   scene.name, scene.size(), scene.width, scene.height, f.rms_distance, f.mean_camera_distance,
                   100 * f.in_front);
    } catch (const Error&) {
      spdlog::info("{}: {} frames {}x{}; optical axes nearly parallel", scene.name, scene.size(), scene.width,
                   scene.height);
    }
  }
}

}  // namespace flat::data::detail
