// flat_latents: precompute video and camera latents of scene folders with the
// frozen Wan 2.1 VAE encoder (paper, Model Training), one latent set per frame
// size and window length (docs/scene_format.md). The work is the latents
// module's (include/flat/latents/encode_latents.h): scene by scene, each
// committed when encoded, resumable, a bad scene reported and skipped.
//
//   flat_latents --configs configs/stage1.yaml configs/stage2.yaml configs/stage3.yaml configs/stage4.yaml
//                --vae Wan2.1_VAE.safetensors --device cuda --precision bf16      (every stage's sets)
//   flat_latents --scenes data/re10k --vae Wan2.1_VAE.safetensors --window 17 --size 176x320
//   flat_latents --scenes data/synth --vae runs/vae/vae.safetensors       # a VAE trained by flat_train (task: vae)
//   flat_latents --scenes data/synth --random-weights --seed 0 --dim 8   # pipeline tests only
//   CUDA_VISIBLE_DEVICES=k flat_latents ... --shard k/N                  # one process per GPU
//
// Exit codes: 0 every scene holds its sets; 1 some scene failed (the rest
// landed; the report lists them) or nothing could be encoded; 2 usage.
#include <filesystem>

#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include "flat/core/cli.h"
#include "flat/core/error.h"
#include "flat/core/pending_log.h"
#include "flat/data/scene.h"
#include "flat/latents/encode_latents.h"

namespace fs = std::filesystem;
using namespace flat;

namespace {

struct Options {
  latents::EncodeOptions encode;
  std::vector<std::string> scenes, configs, overlays, overrides;
  std::string size, shard, report, log_level = "info", camera_rays = "rppc";
  int64_t window = 17, step = 0;
};

std::vector<latents::LatentSetSpec> requested_sets(const Options& o) {
  if (!o.configs.empty()) {
    if (!o.scenes.empty() || !o.size.empty())
      throw cli::UsageError("flat_latents: --configs takes the scenes, sizes and windows from the configs; "
                            "give --scenes/--size/--window or --configs, not both");
    auto sets = latents::latent_sets_for_stages(o.configs, o.overlays, o.overrides);
    for (auto& s : sets) s.step = o.step;
    return sets;
  }
  if (!o.overlays.empty() || !o.overrides.empty())
    throw cli::UsageError("flat_latents: --overlay and --set apply to --configs");
  if (o.scenes.empty()) throw cli::UsageError("flat_latents: give --scenes FOLDER... or --configs STAGE.yaml...");
  latents::LatentSetSpec s;
  s.roots = o.scenes;
  s.window = o.window;
  s.step = o.step;
  s.plucker = o.camera_rays == "rppc,plucker";
  s.origin = "--scenes";
  cli::parse_size_option(o.size, s.height, s.width, "flat_latents");
  if (s.window < 1 || (s.window - 1) % 4 != 0)
    throw cli::UsageError("flat_latents: --window must be 1+4k frames (17, 49, ...), got " + std::to_string(s.window));
  if (s.height % 8 != 0 || s.width % 8 != 0)
    throw cli::UsageError("flat_latents: --size must be multiples of 8 (the VAE downsamples by 8), got " + o.size);
  return {s};
}

int run(Options& o, PendingLog& log) {
  auto& e = o.encode.encoder;
  if (e.random_weights == !e.weights.empty())
    throw cli::UsageError("flat_latents: give exactly one of --vae FILE or --random-weights");
  if (!e.weights.empty() && e.dim != 0) throw cli::UsageError("flat_latents: --dim applies only to --random-weights");
  if (!o.shard.empty()) {
    try {
      latents::parse_shard(o.shard, o.encode.shard_index, o.encode.shard_count);
    } catch (const Error& e) {
      throw cli::UsageError(e.what());
    }
  }
  o.encode.sets = requested_sets(o);
  // The log and the report lie in the first scenes folder; the log appears only if the run succeeds.
  const std::string first = o.encode.sets.front().roots.front();
  const std::string tag = o.encode.shard_count > 1 ? ".shard-" + std::to_string(o.encode.shard_index) + "-of-" +
                                                         std::to_string(o.encode.shard_count)
                                                   : "";
  log.start(o.log_level, (fs::path(first) / ("flat_latents" + tag + ".log")).string());
  o.encode.report_file = !o.report.empty() ? o.report : (fs::path(first) / ("flat_latents_report" + tag + ".json")).string();

  const auto sum = latents::encode_latent_sets(o.encode);
  if (sum.encoded + sum.present == 0 && sum.failed.empty()) {
    std::string windows;
    for (const auto& s : o.encode.sets) windows += (windows.empty() ? "" : " or ") + std::to_string(s.window);
    fail("flat_latents: no scene has --window " + windows + " frames (" + std::to_string(sum.scenes) +
         " scene(s), the longest has " + std::to_string(sum.longest) + "); nothing to encode");
  }
  spdlog::info("flat_latents: {} set(s) encoded ({} windows), {} already present, {} scene(s) too short, {} failed, "
               "in {:.0f} s; report {}",
               sum.encoded, sum.windows, sum.present, sum.too_short, sum.failed.size(), sum.seconds,
               o.encode.report_file);
  if (sum.spread.pairs > 0)
    spdlog::info("flat_latents: the first windows' video latents of {} sampled scenes correlate {:.3f} on average "
                 "(min {:.3f}, max {:.3f}, {} pairs){}",
                 sum.spread_scenes, sum.spread.mean_correlation, sum.spread.min_correlation,
                 sum.spread.max_correlation, sum.spread.pairs,
                 sum.spread.mean_correlation > 0.9 ? ": nearly the same for every scene; a decoder trained on them "
                                                     "can only learn the average scene"
                                                   : "");
  if (e.random_weights) spdlog::warn("flat_latents: reminder: RANDOM encoder weights; the latents are test data only");
  if (!sum.failed.empty()) {
    for (const auto& f : sum.failed)
      spdlog::error("flat_latents: failed: {}{}: {}", f.dir, f.set.empty() ? "" : " (set " + f.set + ")", f.reason);
    log.keep();
    fail("flat_latents: " + std::to_string(sum.failed.size()) + " scene set(s) failed (listed above and in " +
         o.encode.report_file + "); the others landed, and a rerun does only what is missing");
  }
  log.keep();
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"flat_latents: precompute video and camera latents of scene folders with the Wan 2.1 VAE encoder, "
               "one latent set per frame size and window (scene by scene, resumable)"};
  Options o;
  auto& e = o.encode.encoder;
  cli::add_common(app, "flat_latents", o.log_level);
  app.add_option("--scenes", o.scenes, "scene folders, or folders holding scene folders");
  app.add_option("--configs", o.configs,
                 "flat_train stage configs: make every latent set they need (their data size and window) in their "
                 "training and validation datasets, instead of --scenes/--size/--window");
  app.add_option("--overlay", o.overlays,
                 "YAML files layered over each of --configs, in order, as flat_train's further --config files (e.g. "
                 "one that points data.datasets and validation.datasets at your folders)");
  app.add_option("--set", o.overrides,
                 "override a key of each of --configs after the overlays, full key path as flat_train's --set: "
                 "--set 'data.datasets=[{root: data/mine}]'")
      ->take_all();
  app.add_option("--vae", e.weights,
                 "Wan 2.1 VAE weights: .safetensors (Wan or diffusers naming), a diffusers folder, or the "
                 "vae.safetensors of a flat_train VAE stage (its width is read from the file)");
  app.add_option("--vae-prefix", e.weights_prefix, "strip this prefix from the --vae file's keys (default: detected)");
  cli::add_old_name(app, "--weights", "--vae");
  cli::add_old_name(app, "--weights-prefix", "--vae-prefix");
  app.add_flag("--random-weights", e.random_weights,
               "random encoder weights instead of --vae (pipeline tests only; recorded as such)");
  app.add_option("--seed", e.seed, "seed for --random-weights (and the spread sample)");
  app.add_option("--dim", e.dim, "base width of --random-weights (default 96, as Wan 2.1)")->check(CLI::PositiveNumber);
  app.add_option("--window", o.window, "frames per latent window, 1+4k (17 or 49)")->capture_default_str();
  app.add_option("--step", o.step, "frames between window starts (0 = the window, no overlap)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--size", o.size, "frame size HxW to encode at (multiples of 8; default: the scene's, floored to 8)");
  app.add_flag("--overwrite", o.encode.overwrite,
               "replace (re-encode) sets that exist (without it a scene's existing set is kept when made the same way, and "
               "reported when made another way); other sets are never touched");
  app.add_option("--shard", o.shard, "K/N: encode only the scenes K, K+N, ... of the sorted list (one process per GPU)");
  app.add_option("--spread-sample", o.encode.spread_sample,
                 "scenes whose first window enters the spread statistic (a seeded uniform sample; 0 = none)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--report", o.report,
                 "summary JSON (counts, failed scenes and why, the spread; default: flat_latents_report.json in the "
                 "first scenes folder)");
  cli::add_device(app, e.device);
  int threads = 0;
  cli::add_threads(app, threads);
  cli::add_precision(app, e.precision);
  cli::add_old_name(app, "--dtype", "--precision");
  cli::add_store(app, e.store);
  app.add_option("--camera-rays", o.camera_rays,
                 "camera latents to write: rppc (the paper), or rppc,plucker (also Plucker-ray latents, for the "
                 "conditioning ablation: pipeline.model.camera_rays plucker)")
      ->check(CLI::IsMember({"rppc", "rppc,plucker"}));
  app.add_flag("--full", e.full, "encode the whole window at once instead of streaming chunks");
  if (int rc = cli::parse(app, argc, argv); rc >= 0) return rc;
  cli::apply_threads(threads);
  PendingLog log;  // outlives the error report, which it then holds too
  return cli::run([&] { return run(o, log); });
}
