// flat_synth: deterministic synthetic scenes with exact RGB, metric depth and
// camera-space normals, ray cast from analytic shapes (docs/data_tools.md).
//   flat_synth --out DIR --count 8 --seed 0 --family room --frames 49 --size 176x320 --motion mixed
// Scenes are named <family>_<index>; an existing scene of the batch is refused
// before anything is rendered (never mixed with a new one) unless --overwrite,
// and --first-index continues the numbering of an earlier batch.
// Export mode (issue #43): the same rooms in the formats real users bring,
// with known answers (include/flat/data/synthetic_export.h):
//   flat_synth --format re10k|dl3dv --out ROOT --count 4 --seed 0 --frames 17 --size 176x320 --unit 0.5 --corrupt 1
#include <algorithm>
#include <cstdio>
#include <filesystem>

#include <ATen/Parallel.h>
#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include "flat/core/cli.h"
#include "flat/core/error.h"
#include "flat/core/progress.h"
#include "flat/core/shape.h"
#include "flat/core/staged_dir.h"
#include "flat/data/synthetic_export.h"
#include "flat/data/synthetic_scene.h"

namespace fs = std::filesystem;

int main(int argc, char** argv) {
  CLI::App app{"flat_synth: write synthetic scene folders (rooms or object-centric) with exact depth and normals"};
  std::string out, size = "176x320", log_level = "info", device = "cpu";
  int64_t scenes = 1, seed = 0, first = 0;
  int threads = 0;
  bool overwrite = false;
  flat::data::SynthOptions o;
  flat::cli::add_common(app, "flat_synth", log_level);
  app.add_option("--out", out, "output folder (one sub-folder per scene, <family>_<index>)")->required();
  app.add_option("--count", scenes, "number of scenes (export mode: of clips or scenes)")->check(CLI::PositiveNumber);
  flat::cli::add_old_name(app, "--scenes", "--count");
  app.add_option("--first-index", first, "index of the first scene (continue an earlier batch in the same folder)")
      ->check(CLI::NonNegativeNumber);
  flat::cli::add_threads(app, threads);
  flat::cli::add_device(app, device)->description(
      "where the rays are cast: cpu (default), cuda (much faster for large frames; the same scenes to float "
      "rounding) or auto");
  app.add_flag("--overwrite", overwrite, "replace scenes of the same names (each only once its new folder is complete)");
  app.add_option("--seed", seed, "base seed; scene i uses seed*1000003+i");
  app.add_option("--family", o.family, "room or object")->check(CLI::IsMember({"room", "object"}));
  app.add_option("--frames", o.frames, "frames per scene (the paper's videos: 49 to 81)")->check(CLI::Range(1, 1000));
  app.add_option("--size", size, "frame size HxW");
  app.add_option("--motion", o.motion, "pan, zoom, orbit or mixed")->check(CLI::IsMember({"pan", "zoom", "orbit", "mixed"}));
  flat::data::SynthExportOptions x;
  std::string format;
  bool no_truth = false;
  app.add_option("--format", format,
                 "export mode, the format written: the rooms as RealEstate10K clips (re10k) or DL3DV/nerfstudio "
                 "scenes (dl3dv) under --out, with manifest.json and the metric truth (docs/data_tools.md)")
      ->check(CLI::IsMember({"re10k", "dl3dv"}));
  auto* unit_opt = app.add_option("--unit", x.unit, "export mode: metres per written unit of translation and depth "
                                                    "(import with --scale UNIT to restore metres)")
                       ->check(CLI::PositiveNumber);
  auto* corrupt_opt = app.add_option("--corrupt", x.corrupt, "export mode: clips made corrupt on purpose (chosen by "
                                                             "seed, listed in manifest.json)")
                          ->check(CLI::NonNegativeNumber);
  auto* truth_opt = app.add_flag("--no-truth", no_truth, "export mode: leave out the truth folders (metric scene folders)");
  if (int rc = flat::cli::parse(app, argc, argv); rc >= 0) return rc;
  return flat::cli::run([&] {
    o.device = flat::cli::resolve_device(device);
    if (!flat::parse_size(size, o.height, o.width))
      throw flat::cli::UsageError("flat_synth: --size must be HxW (e.g. 176x320), got '" + size + "'");
    if (format.empty()) {
      for (auto* opt : {unit_opt, corrupt_opt, truth_opt})
        if (opt->count()) throw flat::cli::UsageError("flat_synth: " + opt->get_name() + " needs --format re10k|dl3dv");
    } else {
      if (app.count("--first-index"))
        throw flat::cli::UsageError("flat_synth: --format exports --count clips; --first-index is for scene folders");
      x.count = scenes;
      if (x.corrupt > x.count)
        throw flat::cli::UsageError("flat_synth: --corrupt " + std::to_string(x.corrupt) + " exceeds --count " +
                                    std::to_string(x.count));
      // Export mode: ROOT is staged whole; the log goes beside it.
      x.format = format;
      x.seed = uint64_t(seed);
      x.truth = !no_truth;
      x.overwrite = overwrite;
      x.synth = o;
      x.synth.frame_threads = threads;
      const double pixels = double(o.height) * double(o.width);
      flat::cli::check_memory(pixels * 4.0 * (double(o.frames) * 9.0 + 40.0),
                              "flat_synth: a scene of " + std::to_string(o.frames) + " frames at " + size,
                              c10::Device(c10::kCPU));
      at::set_num_threads(1);
      std::string root = out;
      while (root.size() > 1 && root.back() == '/') root.pop_back();
      flat::cli::start_logging(log_level, root + ".log");
      spdlog::info("flat_synth: {} {} {} clip(s) of {} frames at {} into {} (unit {} m, {} corrupt)", x.count,
                   format, o.family, o.frames, size, out, x.unit, x.corrupt);
      flat::Progress progress("flat_synth frames", x.count * o.frames, 5.0);
      x.synth.on_frame = [&] { progress.step(); };
      auto clips = flat::data::export_synthetic(x, root);
      progress.finish();
      std::string corrupt;
      for (const auto& c : clips)
        if (!c.corrupt.empty()) corrupt += (corrupt.empty() ? "" : ", ") + c.name + " (" + c.corrupt + ")";
      spdlog::info("wrote {} {} {} to {} (manifest.json){}", clips.size(), format,
                   format == "re10k" ? "clips" : "scenes", out, corrupt.empty() ? "" : "; corrupt: " + corrupt);
      return 0;
    }
    auto name_of = [&](int64_t i) {
      char name[64];
      std::snprintf(name, sizeof(name), "%s_%06lld", o.family.c_str(), static_cast<long long>(i));
      return std::string(name);
    };
    // Refuse up front: a second batch must not replace the first one's scenes halfway.
    // One listing of --out, not a look-up per scene (--count 100000000 would stat for minutes).
    std::vector<std::string> existing;
    std::error_code ec;
    if (fs::is_directory(out, ec))
      for (const auto& e : fs::directory_iterator(out, ec)) {
        const std::string name = e.path().filename().string(), prefix = o.family + "_";
        if (name.rfind(prefix, 0) != 0) continue;
        const std::string digits = name.substr(prefix.size());  // %06lld: 6 digits or more
        if (digits.size() < 6 || digits.size() > 18 || digits.find_first_not_of("0123456789") != std::string::npos)
          continue;
        const int64_t i = std::stoll(digits);
        if (i >= first && i < first + scenes) existing.push_back(name);
      }
    std::sort(existing.begin(), existing.end());
    if (!existing.empty() && !overwrite)
      flat::fail(out + ": already holds " + std::to_string(existing.size()) + " scene(s) of this batch (" +
                 existing.front() + (existing.size() > 1 ? ", ..." : "") +
                 "); pass --first-index N to continue the numbering, or --overwrite to replace them");
    // Outputs plus the ray-casting buffers of one frame: refuse what cannot fit before rendering.
    const double pixels = double(o.height) * double(o.width);
    flat::cli::check_memory(pixels * 4.0 * (double(o.frames) * 9.0 + 40.0),
                            "flat_synth: a scene of " + std::to_string(o.frames) + " frames at " + size,
                            c10::Device(c10::kCPU));
    // Frames on `threads` plain threads (0: every core), each frame on one
    // intra-op thread: two runs side by side then share the cores instead of
    // spinning against each other (docs/benchmarks.md).
    at::set_num_threads(1);
    fs::create_directories(out);
    flat::cli::start_logging(log_level, (fs::path(out) / "flat_synth.log").string());
    spdlog::info("flat_synth: {} {} scene(s) of {} frames at {} into {} (progress every 5 s)", scenes, o.family,
                 o.frames, size, out);
    flat::Progress progress("flat_synth frames", scenes * o.frames, 5.0);
    for (int64_t i = first; i < first + scenes; ++i) {
      flat::data::SynthOptions s = o;
      s.seed = uint64_t(seed) * 1000003ull + uint64_t(i);
      s.frame_threads = threads;
      s.on_frame = [&] { progress.step(); };
      const std::string name = name_of(i);
      auto rendered = flat::data::render_synthetic_scene(s);
      // Staged: a replaced scene keeps no stale frames, a failed one leaves the old one.
      flat::StagedDir staged((fs::path(out) / name).string(), overwrite);
      flat::data::write_synthetic_scene(rendered, staged.path(), name,
                                        "flat_synth family=" + o.family + " motion=" + rendered.motion +
                                            " seed=" + std::to_string(s.seed));
      staged.commit();
    }
    progress.finish();
    spdlog::info("wrote {} {} scenes ({}..{}) of {} frames at {}x{} to {}", scenes, o.family, name_of(first),
                 name_of(first + scenes - 1), o.frames, o.height, o.width, out);
    return 0;
  });
}
