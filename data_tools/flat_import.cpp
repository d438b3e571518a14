// flat_import: public capture formats -> scene folders (docs/data_tools.md).
//   flat_import transforms --in DIR_OR_JSON --out SCENE_DIR [--max-size 512] [--scale 1]
//   flat_import re10k --in CAMERAS.txt --frames FRAMES_DIR --out SCENE_DIR [--scale S]
#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include "flat/core/error.h"
#include "flat/data/importers.h"

int main(int argc, char** argv) {
  CLI::App app{"flat_import: convert a capture (transforms.json or RealEstate10K) into a FLAT scene folder"};
  std::string format, in, frames, out;
  flat::data::ImportOptions o;
  app.add_option("format", format, "transforms (NeRF / instant-ngp / nerfstudio / DL3DV) or re10k")
      ->required()
      ->check(CLI::IsMember({"transforms", "re10k"}));
  app.add_option("--in", in, "transforms.json (or its folder); for re10k the camera .txt file")->required();
  app.add_option("--frames", frames, "re10k: folder of frames (<timestamp>.png/jpg, or one image per line in name order)");
  app.add_option("--out", out, "output scene folder")->required();
  app.add_option("--name", o.name, "scene name (default: the output folder name)");
  app.add_option("--scale", o.metric_scale, "metric scale factor applied to camera translations")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--max-size", o.max_size, "longest image side after import (0 = keep)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--stride", o.stride, "keep every n-th frame")->check(CLI::PositiveNumber)->capture_default_str();
  app.add_option("--max-frames", o.max_frames, "keep at most this many frames (0 = all)")->capture_default_str();
  app.add_flag("--skip-missing", o.skip_missing, "transforms: skip frames whose image file is missing (with a warning)");
  CLI11_PARSE(app, argc, argv);
  try {
    flat::data::Scene scene;
    if (format == "transforms") {
      scene = flat::data::import_transforms_json(in, out, o);
    } else {
      if (frames.empty()) flat::fail("re10k import needs --frames FRAMES_DIR");
      scene = flat::data::import_re10k(in, frames, out, o);
    }
    spdlog::info("wrote {} ({} frames, {}x{})", scene.json_path(), scene.size(), scene.width, scene.height);
  } catch (...) {
    return flat::report_current_error();
  }
  return 0;
}
