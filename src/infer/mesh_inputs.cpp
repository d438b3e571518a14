#include "infer/mesh_inputs.h"

#include <filesystem>
#include <fstream>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "flat/core/error.h"
#include "flat/data/frame_resize.h"
#include "flat/data/scene_frames.h"
#include "flat/export/triangle_ply.h"

namespace fs = std::filesystem;

namespace flat::infer {

MeshSource read_mesh_source(const MeshRunOptions& o) {
  MeshSource s;
  std::string ply = o.from;
  if (fs::is_directory(o.from)) {
    ply = o.from + "/scene.ply";
    FLAT_CHECK(fs::is_regular_file(ply), o.from + ": no scene.ply (expected a flat_infer output folder)");
    const std::string summary = o.from + "/summary.json";
    if (fs::is_regular_file(summary)) {
      nlohmann::json j;
      try {
        std::ifstream in(summary);
        j = nlohmann::json::parse(in);
      } catch (const std::exception& e) {
        fail(summary + ": not valid JSON: " + e.what());
      }
      if (j.contains("representation") && j["representation"] != "triangles")
        fail(o.from + ": holds a " + j["representation"].get<std::string>() +
             " scene; flat_mesh refines and meshes triangle scenes only");
      if (j.contains("scene_dir")) s.scene_dir = j["scene_dir"].get<std::string>();
      if (j.contains("window")) s.window = j["window"].get<int64_t>();
      if (j.contains("latent_set")) s.latent_set = j["latent_set"].get<std::string>();
    }
  }
  s.soup = exporter::read_triangle_ply(ply);
  FLAT_CHECK(s.soup.vertices.size(0) > 0, ply + ": the soup has no triangles");
  if (!o.scene_dir.empty()) s.scene_dir = o.scene_dir;
  if (o.window >= 0) s.window = o.window;
  if (!o.latent_set.empty()) s.latent_set = o.latent_set;
  FLAT_CHECK(!s.scene_dir.empty(), "--scene: which scene folder holds the frames to fit? (" + o.from +
                                       " does not name one: flat_infer records it only for scene-folder input)");
  if (s.window < 0) s.window = 0;
  return s;
}

mesh::ViewTargets load_window_targets(const data::Scene& scene, int64_t window, bool depth, bool normals) {
  FLAT_CHECK(scene.latents.present(), scene.json_path() + ": the scene has no latents, so no window to fit");
  FLAT_CHECK(window < int64_t(scene.latents.windows.size()),
             fmt::format("{}: window {} does not exist (the scene has {})", scene.json_path(), window,
                         scene.latents.windows.size()));
  const auto w = scene.latents.windows[size_t(window)];
  std::vector<int64_t> idx;
  for (int64_t i = 0; i < w.count; ++i) idx.push_back(w.start + i);
  FLAT_CHECK(!depth || scene.has_depth, scene.json_path() + ": the depth term needs depth maps, the scene has none");
  FLAT_CHECK(!normals || scene.has_normals, scene.json_path() + ": scoring normals needs normal maps");
  auto frames = data::load_frames(scene, idx, depth, normals);
  const int64_t H = scene.latents.height > 0 ? scene.latents.height : scene.height;
  const int64_t W = scene.latents.width > 0 ? scene.latents.width : scene.width;
  const auto cams = scene.cameras(idx);
  const auto intr = data::fit_frames(frames, cams.intrinsics, H, W);
  return {frames.images, frames.depth, frames.normals, camera::Cameras{intr, cams.c2w}};
}

ViewSplit split_views(int64_t views, int64_t every) {
  std::vector<int64_t> fit, held;
  for (int64_t i = 0; i < views; ++i) (every > 1 && i % every == every / 2 ? held : fit).push_back(i);
  FLAT_CHECK(!fit.empty(), "--holdout-every: no view left to fit");
  return {at::tensor(fit, at::kLong), at::tensor(held, at::kLong)};
}

}  // namespace flat::infer
