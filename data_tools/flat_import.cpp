// flat_import: public capture formats -> scene folders (docs/data_tools.md).
//   flat_import transforms --in DIR_OR_JSON --out SCENE_DIR [--max-side 512] [--scale 1]
//   flat_import re10k --in CAMERAS.txt --frames-dir FRAMES_DIR --out SCENE_DIR [--scale S]
// Batch (a dataset, one scene per clip; src/data/import_batch.cpp):
//   flat_import re10k --in CAMERAS_DIR --frames-dir FRAMES_ROOT --out OUT_ROOT [--jobs 4]
//   flat_import transforms --in ROOT_OF_SCENE_FOLDERS --out OUT_ROOT [--jobs 4] [--depth 'ROOT/{clip}/depth']
// The scene appears whole or not at all; an existing one is kept unless --overwrite.
#include <string>
#include <utility>

#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include "flat/core/cli.h"
#include "flat/core/error.h"
#include "flat/data/import_batch.h"
#include "flat/data/importers.h"

int main(int argc, char** argv) {
  CLI::App app{"flat_import: convert a capture (transforms.json or RealEstate10K) into a FLAT scene folder"};
  std::string format, in, frames_dir, out, log_level = "info";
  flat::data::ImportOptions o;
  flat::cli::add_common(app, "flat_import", log_level);
  app.add_option("format", format, "transforms (NeRF / instant-ngp / nerfstudio / DL3DV) or re10k")
      ->required()
      ->check(CLI::IsMember({"transforms", "re10k"}));
  app.add_option("--in", in,
                 "input: transforms.json (or its folder), or a folder of scene folders (batch); for re10k the camera "
                 ".txt file, or a folder of <clip>.txt files (batch)")
      ->required();
  app.add_option("--frames-dir", frames_dir,
                 "re10k: folder of frames (<timestamp>.png/jpg, or one image per line in name order); batch: the "
                 "root holding <clip>/ frame folders");
  app.add_option("--out", out,
                 "output scene folder (must not exist unless --overwrite); batch: the root receiving <clip>/ scenes")
      ->required();
  app.add_flag("--overwrite", o.overwrite,
               "replace an existing scene folder (only once the new one is complete); batch: import every clip "
               "again instead of skipping those already present");
  app.add_option("--name", o.name, "scene name (default: the output folder name; not in batch mode)");
  int jobs = 0;
  app.add_option("--jobs", jobs, "batch: clips imported at once, one thread each (0: min(cores, 4))")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--scale", o.metric_scale, "metric scale factor applied to camera translations")
      ->check(CLI::PositiveNumber);
  app.add_option("--max-side", o.max_size, "longest image side after import in pixels (0 = keep)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--stride", o.stride, "keep every n-th frame")->check(CLI::PositiveNumber);
  app.add_option("--max-frames", o.max_frames, "keep at most this many frames (0 = all)")->check(CLI::NonNegativeNumber);
  app.add_flag("--skip-missing", o.skip_missing, "transforms: skip frames whose image file is missing (with a warning)");
  // --depth, --normals and their formats; their folders, or batch {clip} patterns, checked (geometry_maps.h).
  flat::data::add_geometry_options(app, o.geometry);
  int threads = 0;
  flat::cli::add_threads(app, threads);
  app.footer(
      "Batch mode: --in a folder of clips (re10k: <clip>.txt files; transforms: scene folders with transforms.json) "
      "imports each into <out>/<clip>/, skipping those already there (a rerun resumes); a clip that fails is logged "
      "and skipped, and <out>/import_summary.json lists every failure with its reason. --depth/--normals then name "
      "roots holding one <clip>/ folder of maps per clip, or patterns in which {clip} stands for the clip's name "
      "(maps inside each DL3DV scene folder: --depth 'IN/{clip}/depth' --normals 'IN/{clip}/normals'); {clip} is "
      "a usage error for one clip.\n"
      "Exit codes: 0 done (batch: every clip imported or already present); 1 an error, or (batch) at least one clip "
      "failed, after the others were imported; 2 a usage error.");
  if (int rc = flat::cli::parse(app, argc, argv); rc >= 0) return rc;
  flat::cli::apply_threads(threads);
  return flat::cli::run([&] {
    if (format == "re10k" && frames_dir.empty()) throw flat::cli::UsageError("flat_import re10k needs --frames-dir DIR");
    if (format == "transforms" && !frames_dir.empty())
      throw flat::cli::UsageError("flat_import transforms takes no --frames-dir (images are named in transforms.json)");
    const auto batch_format = flat::data::batch_format(format);
    if (flat::data::is_batch_input(batch_format, in)) {
      if (!o.name.empty())
        throw flat::cli::UsageError("--name names one scene; in batch mode (--in " + in +
                                    " is a folder of clips) each scene is named after its clip");
      flat::cli::start_logging(log_level, out + "/flat_import.log");
      flat::data::BatchImportOptions b;
      b.format = batch_format;
      b.in = in;
      b.frames_root = frames_dir;
      b.out_root = out;
      b.import = o;
      b.jobs = jobs;
      return flat::data::import_batch(b).ok() ? flat::cli::kExitOk : flat::cli::kExitRuntime;
    }
    if (app.count("--jobs"))
      throw flat::cli::UsageError("--jobs applies to batch mode (--in a folder of clips); " + in + " is one clip");
    for (const auto& [flag, dir] : {std::pair<const char*, std::string>{"--depth", o.geometry.depth_dir},
                                    {"--normals", o.geometry.normals_dir}})
      if (dir.find(flat::data::kClipPlaceholder) != std::string::npos)
        throw flat::cli::UsageError(std::string(flag) + " " + dir + ": {clip} stands for each clip's name in batch " +
                                    "mode (--in a folder of clips); " + in + " is one clip: name its maps folder");
    // The log lands beside the scene, <out>.log (outside it: the staged folder holds the scene only).
    std::string log = out;
    while (log.size() > 1 && log.back() == '/') log.pop_back();
    flat::cli::start_logging(log_level, log + ".log");
    const flat::data::Scene scene = format == "transforms" ? flat::data::import_transforms_json(in, out, o)
                                                           : flat::data::import_re10k(in, frames_dir, out, o);
    spdlog::info("wrote {} ({} frames, {}x{})", scene.json_path(), scene.size(), scene.width, scene.height);
    return 0;
  });
}
