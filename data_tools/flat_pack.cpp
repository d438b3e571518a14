// flat_pack: pack scene folders into frames.safetensors for fast loading
// (include/flat/data/pack.h). Accepts scene folders or folders of scenes.
//   flat_pack --scenes data/synth data/re10k/abc --remove-files
#include <filesystem>

#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include "flat/core/error.h"
#include "flat/core/progress.h"
#include "flat/data/pack.h"
#include "flat/data/scene.h"

int main(int argc, char** argv) {
  namespace fs = std::filesystem;
  CLI::App app{"flat_pack: write frames.safetensors (images U8, depth F32, normals F16) for each scene"};
  std::vector<std::string> roots;
  bool remove = false;
  app.add_option("--scenes", roots, "scene folders, or folders holding scene folders")->required();
  app.add_flag("--remove-files", remove, "delete the per-frame image/depth/normal files after packing");
  CLI11_PARSE(app, argc, argv);
  try {
    std::vector<std::string> dirs;
    for (const auto& r : roots) {
      if (fs::exists(fs::path(r) / flat::data::kSceneFile)) {
        dirs.push_back(r);
        continue;
      }
      if (!fs::is_directory(r)) flat::fail(r + ": not a folder");
      std::vector<std::string> sub;
      for (const auto& e : fs::directory_iterator(r))
        if (fs::exists(e.path() / flat::data::kSceneFile)) sub.push_back(e.path().string());
      std::sort(sub.begin(), sub.end());
      if (sub.empty()) flat::fail(r + ": no scene folders (with scene.json) inside");
      dirs.insert(dirs.end(), sub.begin(), sub.end());
    }
    flat::Progress progress("flat_pack", int64_t(dirs.size()));
    for (const auto& d : dirs) {
      auto scene = flat::data::read_scene(d);
      flat::data::pack_scene(scene, remove);
      progress.step();
    }
    progress.finish();
    spdlog::info("packed {} scenes", dirs.size());
  } catch (...) {
    return flat::report_current_error();
  }
  return 0;
}
