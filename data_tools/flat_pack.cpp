// flat_pack: pack scene folders into frames.safetensors for fast loading
// (include/flat/data/pack.h). Accepts scene folders or folders of scenes.
//   flat_pack --scenes data/synth data/re10k/abc --remove-files
#include <filesystem>

#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include "flat/core/cli.h"
#include "flat/core/error.h"
#include "flat/core/pending_log.h"
#include "flat/core/progress.h"
#include "flat/data/pack.h"
#include "flat/data/scene.h"

int main(int argc, char** argv) {
  namespace fs = std::filesystem;
  CLI::App app{"flat_pack: write frames.safetensors (images U8, depth F32, normals F16) for each scene"};
  std::vector<std::string> roots;
  std::string log_level = "info";
  bool remove = false;
  flat::cli::add_common(app, "flat_pack", log_level);
  app.add_option("--scenes", roots, "scene folders, or folders holding scene folders")->required();
  app.add_flag("--remove-files", remove, "delete the per-frame image/depth/normal files after packing");
  int threads = 0;
  flat::cli::add_threads(app, threads);
  if (int rc = flat::cli::parse(app, argc, argv); rc >= 0) return rc;
  flat::cli::apply_threads(threads);
  flat::PendingLog log;  // in an input folder: appears there only if the run succeeds
  return flat::cli::run([&] {
    std::vector<std::string> dirs;
    for (const auto& r : roots) {
      auto sub = flat::data::scene_dirs_under(r);
      dirs.insert(dirs.end(), sub.begin(), sub.end());
    }
    log.start(log_level, (fs::path(roots.front()) / "flat_pack.log").string());
    flat::Progress progress("flat_pack", int64_t(dirs.size()));
    for (const auto& d : dirs) {
      auto scene = flat::data::read_scene(d);
      flat::data::pack_scene(scene, remove);
      progress.step();
    }
    progress.finish();
    spdlog::info("packed {} scenes", dirs.size());
    log.keep();
    return 0;
  });
}
