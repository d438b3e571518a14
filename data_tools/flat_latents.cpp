// flat_latents: precompute the latents of scene folders with the frozen Wan 2.1
// VAE encoder (paper, Model Training: "For each video, we precompute its
// latents using the frozen VAE"): for windows of F = 1+4k consecutive frames,
// the normalised video latent (16,T',H/8,W/8) and the RPPC camera latents
// (32,T',H/8,W/8), stored in <scene>/latents.safetensors and scene.json
// (docs/scene_format.md). Whether the encoder was pretrained or random is
// written to both and printed loudly.
//
//   flat_latents --scenes data/re10k --weights Wan2.1_VAE.safetensors --window 17 --size 176x320 --device cuda --dtype bf16
//   flat_latents --scenes data/synth --random-weights --seed 0 --dim 8   # pipeline tests only
#include <cstdio>
#include <filesystem>

#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/progress.h"
#include "flat/data/frame_resize.h"
#include "flat/data/scene.h"
#include "flat/data/scene_frames.h"
#include "flat/data/scene_latents.h"
#include "flat/model/camera_latents.h"
#include "flat/model/wan_vae.h"
#include "flat/model/weights.h"

namespace fs = std::filesystem;
using namespace flat;

namespace {

struct Options {
  std::vector<std::string> scenes;
  std::string weights, size, device = "cpu", dtype = "fp32", store = "float32";
  bool random_weights = false, full = false;
  int64_t seed = 0, dim = 96, window = 17, step = 0;
};

std::vector<std::string> scene_dirs(const std::vector<std::string>& roots) {
  std::vector<std::string> dirs;
  for (const auto& r : roots) {
    if (fs::exists(fs::path(r) / data::kSceneFile)) {
      dirs.push_back(r);
      continue;
    }
    if (!fs::is_directory(r)) fail(r + ": not a folder");
    std::vector<std::string> sub;
    for (const auto& e : fs::directory_iterator(r))
      if (fs::exists(e.path() / data::kSceneFile)) sub.push_back(e.path().string());
    std::sort(sub.begin(), sub.end());
    if (sub.empty()) fail(r + ": no scene folders (with scene.json) inside");
    dirs.insert(dirs.end(), sub.begin(), sub.end());
  }
  return dirs;
}

void run(const Options& o) {
  FLAT_CHECK(o.random_weights != !o.weights.empty(), "flat_latents: give exactly one of --weights FILE or --random-weights");
  FLAT_CHECK(o.weights.empty() || o.dim == 96, "flat_latents: --dim applies only to --random-weights");
  FLAT_CHECK(o.window >= 1 && (o.window - 1) % 4 == 0, "flat_latents: --window must be 1+4k frames (17, 49, ...)");
  if (o.device == "cuda") FLAT_CHECK(torch::cuda::is_available(), "flat_latents: --device cuda but no CUDA device");
  int64_t H = 0, W = 0;
  if (!o.size.empty()) {
    long long h = 0, w = 0;
    char x = 0;
    if (std::sscanf(o.size.c_str(), "%lld%c%lld", &h, &x, &w) != 3 || (x != 'x' && x != 'X'))
      fail("flat_latents: --size must be HxW, got '" + o.size + "'");
    H = h;
    W = w;
    FLAT_CHECK(H % 8 == 0 && W % 8 == 0, "flat_latents: --size must be multiples of 8 (the VAE downsamples by 8)");
  }

  model::WanVAEConfig config;
  config.dim = o.dim;
  if (o.random_weights) torch::manual_seed(o.seed);
  model::WanVAE vae(config);
  data::LatentInfo info;
  info.seed = o.seed;
  info.dtype = o.store;
  if (o.random_weights) {
    info.encoder = "random";
    spdlog::warn("=====================================================================");
    spdlog::warn("flat_latents: RANDOM ENCODER WEIGHTS (seed {}, dim {}). These latents are", o.seed, o.dim);
    spdlog::warn("NOT the Wan 2.1 latents: use them only to test the pipeline. Recorded as");
    spdlog::warn("encoder=\"random\" in latents.safetensors and scene.json.");
    spdlog::warn("=====================================================================");
  } else {
    auto report = model::load_weights(*vae, o.weights);
    info.encoder = "pretrained";
    info.weights = fs::path(o.weights).filename().string();
    spdlog::info("flat_latents: PRETRAINED encoder weights from {} ({})", o.weights, report.summary());
  }
  vae->eval();
  vae->to(o.device == "cuda" ? torch::kCUDA : torch::kCPU, o.dtype == "bf16" ? torch::kBFloat16 : torch::kFloat);
  auto weight = vae->conv2->weight;
  torch::NoGradGuard no_grad;

  auto dirs = scene_dirs(o.scenes);
  Progress progress("flat_latents", int64_t(dirs.size()));
  int64_t written = 0;
  for (const auto& dir : dirs) {
    data::Scene scene = data::read_scene(dir);
    const int64_t h = H ? H : scene.height - scene.height % 8, w = W ? W : scene.width - scene.width % 8;
    const int64_t step = o.step > 0 ? o.step : o.window;
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
      auto video = (frames.images.permute({1, 0, 2, 3}).unsqueeze(0) * 2 - 1).to(weight.device(), weight.scalar_type());
      data::WindowLatents l;
      l.video = vae->encode(video, !o.full)[0].to(at::kCPU, at::kFloat);
      l.camera = model::encode_camera_latents(vae, cams.to(weight.device()), h, w, !o.full)[0].to(at::kCPU, at::kFloat);
      latents.push_back(l);
      si.windows.push_back({start, o.window});
    }
    if (latents.empty()) {
      spdlog::warn("flat_latents: {}: {} frames, fewer than one window of {}; skipped", dir, scene.size(), o.window);
    } else {
      data::write_scene_latents(scene, si, latents);
      ++written;
    }
    progress.step();
  }
  progress.finish();
  spdlog::info("flat_latents: wrote latents for {} of {} scenes (window {}, encoder {})", written, dirs.size(), o.window,
               info.encoder);
  if (o.random_weights) spdlog::warn("flat_latents: reminder: RANDOM encoder weights; the latents are test data only");
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"flat_latents: precompute video and camera latents of scene folders with the Wan 2.1 VAE encoder"};
  Options o;
  app.add_option("--scenes", o.scenes, "scene folders, or folders holding scene folders")->required();
  app.add_option("--weights", o.weights, "Wan 2.1 VAE weights (.safetensors, Wan or diffusers naming)");
  app.add_flag("--random-weights", o.random_weights, "random encoder (pipeline tests only; recorded as such)");
  app.add_option("--seed", o.seed, "seed for --random-weights")->capture_default_str();
  app.add_option("--dim", o.dim, "base width (96 = Wan 2.1; smaller only with --random-weights)")->capture_default_str();
  app.add_option("--window", o.window, "frames per latent window, 1+4k (17 or 49)")->capture_default_str();
  app.add_option("--step", o.step, "frames between window starts (default: the window, no overlap)");
  app.add_option("--size", o.size, "frame size HxW to encode at (multiples of 8; default: the scene's, floored to 8)");
  app.add_option("--device", o.device, "cpu or cuda")->check(CLI::IsMember({"cpu", "cuda"}))->capture_default_str();
  app.add_option("--dtype", o.dtype, "compute dtype fp32 or bf16")->check(CLI::IsMember({"fp32", "bf16"}))->capture_default_str();
  app.add_option("--store", o.store, "stored dtype float32, bfloat16 or float16")
      ->check(CLI::IsMember({"float32", "bfloat16", "float16"}))
      ->capture_default_str();
  app.add_flag("--full", o.full, "encode the whole window at once instead of streaming chunks");
  CLI11_PARSE(app, argc, argv);
  try {
    run(o);
  } catch (...) {
    return flat::report_current_error();
  }
  return 0;
}
