// flat_latents: precompute the latents of scene folders with the frozen Wan 2.1
// VAE encoder (paper, Model Training: "For each video, we precompute its
// latents using the frozen VAE"): for windows of F = 1+4k consecutive frames,
// the normalised video latent (16,T',H/8,W/8) and the RPPC camera latents
// (32,T',H/8,W/8), stored in <scene>/latents.safetensors and scene.json
// (docs/scene_format.md). Whether the encoder was pretrained or random is
// written to both and printed loudly.
//
//   flat_latents --scenes data/re10k --weights Wan2.1_VAE.safetensors --window 17 --size 176x320 --device cuda --precision bf16
//   flat_latents --scenes data/synth --vae runs/vae/vae.safetensors       # a VAE trained by flat_train (task: vae)
//   flat_latents --scenes data/synth --random-weights --seed 0 --dim 8   # pipeline tests only
//
// The VAE's width is read from the weights file. At the end the spread of the
// latents is printed: the mean Pearson correlation between the first windows
// of different scenes (a collapsed encoder gives about 0.99).
//
// Scenes shorter than one window are skipped with a warning; when no scene is
// long enough the run stops before loading the encoder, with exit code 1.
#include <filesystem>

#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/core/cli.h"
#include "flat/core/error.h"
#include "flat/core/pending_log.h"
#include "flat/core/progress.h"
#include "flat/core/shape.h"
#include "flat/data/frame_resize.h"
#include "flat/data/scene.h"
#include "flat/data/scene_frames.h"
#include "flat/data/scene_latents.h"
#include "flat/eval/latent_spread.h"
#include "flat/model/camera_latents.h"
#include "flat/model/wan_vae.h"
#include "flat/model/weights.h"

namespace fs = std::filesystem;
using namespace flat;

namespace {

struct Options {
  std::vector<std::string> scenes;
  std::string weights, weights_prefix, size, device = "auto", precision = "fp32", store = "fp32", log_level = "info";
  std::string camera_rays = "rppc";  // "rppc" or "rppc,plucker" (also the Plucker latents of the ablation)
  bool random_weights = false, full = false;
  int64_t seed = 0, dim = 0, window = 17, step = 0;
};

int64_t window_count(int64_t frames, int64_t window, int64_t step) {
  return frames < window ? 0 : (frames - window) / step + 1;
}

void run(const Options& o, PendingLog& log) {
  if (o.random_weights == !o.weights.empty())
    throw cli::UsageError("flat_latents: give exactly one of --weights FILE or --random-weights");
  if (!o.weights.empty() && o.dim != 0) throw cli::UsageError("flat_latents: --dim applies only to --random-weights");
  if (o.window < 1 || (o.window - 1) % 4 != 0)
    throw cli::UsageError("flat_latents: --window must be 1+4k frames (17, 49, ...), got " + std::to_string(o.window));
  int64_t H = 0, W = 0;
  if (!o.size.empty()) {
    if (!parse_size(o.size, H, W))
      throw cli::UsageError("flat_latents: --size must be HxW (e.g. 176x320), got '" + o.size + "'");
    if (H % 8 != 0 || W % 8 != 0)
      throw cli::UsageError("flat_latents: --size must be multiples of 8 (the VAE downsamples by 8), got " + o.size);
  }
  const auto device = cli::resolve_device(o.device);
  const int64_t step = o.step > 0 ? o.step : o.window;
  // The width: --dim for a random encoder (default 96), else the weights file's.
  const int64_t dim = o.random_weights ? (o.dim > 0 ? o.dim : 96) : model::vae_dim_of_file(o.weights);

  // Every scene is read first: a run that would encode nothing stops here.
  std::vector<std::string> dirs;
  for (const auto& root : o.scenes) {
    auto sub = data::scene_dirs_under(root);
    dirs.insert(dirs.end(), sub.begin(), sub.end());
  }
  // The log lies in the first scenes folder, an input: it appears there only if the run succeeds.
  log.start(o.log_level, (fs::path(o.scenes.front()) / "flat_latents.log").string());
  std::vector<data::Scene> scenes;
  int64_t total_windows = 0, longest = 0, largest = 0;
  for (const auto& dir : dirs) {
    data::Scene scene = data::read_scene(dir);
    longest = std::max(longest, scene.size());
    const int64_t n = window_count(scene.size(), o.window, step);
    if (n == 0) {
      spdlog::warn("flat_latents: {}: {} frames, fewer than one window of {}; skipped", dir, scene.size(), o.window);
      continue;
    }
    total_windows += n;
    largest = std::max(largest, H ? H * W : (scene.height - scene.height % 8) * (scene.width - scene.width % 8));
    scenes.push_back(std::move(scene));
  }
  if (scenes.empty())
    fail("flat_latents: no scene has --window " + std::to_string(o.window) + " frames (" + std::to_string(dirs.size()) +
         " scene(s), the longest has " + std::to_string(longest) + "); nothing to encode");
  // A window's frames plus the encoder's widest activations (dim channels at full size, a
  // chunk of 4 frames when streaming): refuse what cannot fit before allocating.
  const double frames_in_flight = o.full ? double(o.window) : 4.0;
  cli::check_memory(double(largest) * 4.0 * (3.0 * double(o.window) + 6.0 * double(dim) * frames_in_flight),
                    "flat_latents: encoding a window of " + std::to_string(o.window) + " frames", device);

  model::WanVAEConfig config;
  config.dim = dim;
  if (o.random_weights) torch::manual_seed(o.seed);
  model::WanVAE vae(config);
  data::LatentInfo info;
  info.seed = o.seed;
  info.dtype = cli::stored_dtype_name(o.store);
  if (o.random_weights) {
    info.encoder = "random";
    spdlog::warn("=====================================================================");
    spdlog::warn("flat_latents: RANDOM ENCODER WEIGHTS (seed {}, dim {}). These latents are", o.seed, dim);
    spdlog::warn("NOT the Wan 2.1 latents: use them only to test the pipeline. Recorded as");
    spdlog::warn("encoder=\"random\" in latents.safetensors and scene.json.");
    spdlog::warn("=====================================================================");
  } else {
    model::LoadSpec spec;
    spec.strip_prefix = o.weights_prefix;
    auto report = model::load_weights(*vae, o.weights, spec);
    info.encoder = "pretrained";
    info.weights = fs::path(o.weights).filename().string();
    spdlog::info("flat_latents: PRETRAINED encoder weights from {} (dim {}; {})", o.weights, dim, report.summary());
  }
  vae->eval();
  vae->to(device, cli::precision_dtype(o.precision));
  auto weight = vae->conv2->weight;
  torch::NoGradGuard no_grad;

  // Progress per window: one scene can take minutes.
  Progress progress("flat_latents windows", total_windows, 5.0);
  std::vector<at::Tensor> first_windows;  // for the spread across scenes
  // Every scene is staged first and committed only when all are encoded: a
  // failure on scene k leaves scenes 0..k-1 as they were, not half updated.
  std::vector<data::StagedLatents> staged;
  try {
    for (auto& scene : scenes) {
      if (const int stale = data::remove_stale_staged_latents(scene))
        spdlog::warn("{}: removed {} staged latent file(s) that a killed run left", scene.dir, stale);
      const int64_t h = H ? H : scene.height - scene.height % 8, w = W ? W : scene.width - scene.width % 8;
      data::LatentInfo si = info;
      si.height = h;
      si.width = w;
      std::vector<data::WindowLatents> latents;
      for (int64_t start = 0; start + o.window <= scene.size(); start += step) {
        std::vector<int64_t> idx(size_t(o.window));
        for (int64_t i = 0; i < o.window; ++i) idx[size_t(i)] = start + i;
        data::FrameBatch frames = data::load_frames(scene, idx, false, false);
        auto cams = scene.cameras(idx);
        cams.intrinsics = data::fit_frames(frames, cams.intrinsics, h, w);  // crop + resize; intrinsics follow
        auto video =
            (frames.images.permute({1, 0, 2, 3}).unsqueeze(0) * 2 - 1).to(weight.device(), weight.scalar_type());
        data::WindowLatents l;
        l.video = vae->encode(video, !o.full)[0].to(at::kCPU, at::kFloat);
        l.camera =
            model::encode_camera_latents(vae, cams.to(weight.device()), h, w, !o.full)[0].to(at::kCPU, at::kFloat);
        if (o.camera_rays == "rppc,plucker")
          l.camera_plucker = model::encode_camera_latents(vae, cams.to(weight.device()), h, w, !o.full, "plucker")[0]
                                 .to(at::kCPU, at::kFloat);
        check_finite(l.video, scene.dir + ": window at frame " + std::to_string(start) + ": video latent");
        if (latents.empty()) first_windows.push_back(l.video);
        latents.push_back(l);
        si.windows.push_back({start, o.window});
        progress.step();
      }
      staged.push_back(data::stage_scene_latents(scene, si, latents));
    }
  } catch (...) {
    for (const auto& s : staged) data::discard_staged_latents(s);
    throw;
  }
  for (size_t i = 0; i < scenes.size(); ++i) data::commit_scene_latents(scenes[i], staged[i]);
  progress.finish();
  spdlog::info("flat_latents: wrote latents for {} of {} scenes (window {}, encoder {})", scenes.size(), dirs.size(),
               o.window, info.encoder);
  const auto spread = eval::latent_spread(first_windows);
  if (spread.pairs > 0)
    spdlog::info("flat_latents: the first windows' video latents of different scenes correlate {:.3f} on average "
                 "(min {:.3f}, max {:.3f}, {} pairs){}",
                 spread.mean_correlation, spread.min_correlation, spread.max_correlation, spread.pairs,
                 spread.mean_correlation > 0.9 ? ": nearly the same for every scene; a decoder trained on them can "
                                                 "only learn the average scene"
                                               : "");
  if (o.random_weights) spdlog::warn("flat_latents: reminder: RANDOM encoder weights; the latents are test data only");
  log.keep();
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"flat_latents: precompute video and camera latents of scene folders with the Wan 2.1 VAE encoder"};
  Options o;
  cli::add_common(app, "flat_latents", o.log_level);
  app.add_option("--scenes", o.scenes, "scene folders, or folders holding scene folders")->required();
  app.add_option("--weights,--vae", o.weights,
                 "Wan 2.1 VAE weights: .safetensors (Wan or diffusers naming), a diffusers folder, or the "
                 "vae.safetensors of a flat_train VAE stage (its width is read from the file)");
  app.add_option("--weights-prefix", o.weights_prefix, "strip this prefix from the file's keys (default: detected)");
  app.add_flag("--random-weights", o.random_weights, "random encoder (pipeline tests only; recorded as such)");
  app.add_option("--seed", o.seed, "seed for --random-weights");
  app.add_option("--dim", o.dim, "base width of --random-weights (default 96, as Wan 2.1)")->check(CLI::PositiveNumber);
  app.add_option("--window", o.window, "frames per latent window, 1+4k (17 or 49)");
  app.add_option("--step", o.step, "frames between window starts (0 = the window, no overlap)")->check(CLI::NonNegativeNumber);
  app.add_option("--size", o.size, "frame size HxW to encode at (multiples of 8; default: the scene's, floored to 8)");
  cli::add_device(app, o.device);
  int threads = 0;
  cli::add_threads(app, threads);
  cli::add_precision(app, o.precision);
  app.add_option("--dtype", o.precision, "old name of --precision")->check(CLI::IsMember({"fp32", "bf16"}))->group("");
  cli::add_store(app, o.store);
  app.add_option("--camera-rays", o.camera_rays,
                 "camera latents to write: rppc (the paper), or rppc,plucker (also Plucker-ray latents, for the "
                 "conditioning ablation: pipeline.model.camera_rays plucker)")
      ->check(CLI::IsMember({"rppc", "rppc,plucker"}));
  app.add_flag("--full", o.full, "encode the whole window at once instead of streaming chunks");
  if (int rc = cli::parse(app, argc, argv); rc >= 0) return rc;
  cli::apply_threads(threads);
  PendingLog log;  // outlives the error report, which it then holds too
  return cli::run([&] {
    run(o, log);
    return 0;
  });
}
