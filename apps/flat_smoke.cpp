// flat_smoke: the end-to-end run behind README command 1, until the staged
// trainer (flat_train) exists. It drives every module that exists through a
// few optimisation steps, exactly as training will:
//
//   scene folders with precomputed latents (flat_synth + flat_latents)
//     -> data::Loader (input window, seen/unseen target views, stage resolution)
//     -> model::SceneDecoder (camera adapter + Wan decoder without the last x2 + heads)
//     -> primitives::build_triangles (ray-centred triangles, one per 2x2 block)
//     -> render::rasterize (FLAT window) into the target views
//     -> loss::Objective (L2, disparity, normals, opacity) -> AdamW
//
// and writes a run folder: config.yaml (the effective config), logs/,
// metrics/smoke.json (loss per step), renders/final.safetensors and the final
// triangle soup as PLY. The default config is embedded (tiny widths, CPU) and
// every key can be overridden with --config FILE and --set a.b=value.
#include <cmath>
#include <fstream>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include "flat/camera/camera_json.h"
#include "flat/core/atomic_file.h"
#include "flat/core/config.h"
#include "flat/core/error.h"
#include "flat/core/log.h"
#include "flat/core/progress.h"
#include "flat/core/run_dir.h"
#include "flat/core/tensor_io.h"
#include "flat/data/loader.h"
#include "flat/export/triangle_ply.h"
#include "flat/loss/objective.h"
#include "flat/model/scene_decoder.h"
#include "flat/primitives/ray_triangles.h"
#include "flat/render/rasterize.h"

namespace {

using namespace flat;

struct SmokeConfig {
  std::string run_dir = "runs/smoke";
  int64_t steps = 30;
  double lr = 2e-3;
  double weight_decay = 0.0;
  std::string device = "cpu";
  int64_t seed = 0;
  data::LoaderConfig data;
  model::SceneDecoderConfig model;
  primitives::TriangleParamConfig triangles;
  render::RasterSettings raster;
  loss::LossConfig loss;

  template <class V>
  void visit(V& v) {
    v.field("run_dir", run_dir, "run folder (config, logs, metrics, renders)");
    v.field("steps", steps, config::positive(), "optimisation steps");
    v.field("lr", lr, config::positive(), "AdamW learning rate");
    v.field("weight_decay", weight_decay, config::non_negative(), "AdamW decoupled weight decay");
    v.field("device", device, config::one_of({"cpu", "cuda"}), "cpu or cuda");
    v.field("seed", seed, "seed of the model initialisation");
    v.section("data", data);
    v.section("model", model);
    v.section("triangles", triangles);
    v.section("raster", raster);
    v.section("loss", loss);
  }
};

// Tiny on purpose: a 2-core CPU runs it in about a minute. The scenes come
// from `flat_synth ... --frames 9 --size 48x80` and `flat_latents --window 9`.
const char* kDefaultConfig = R"(
run_dir: runs/smoke
steps: 30
lr: 0.002
device: cpu
data:
  datasets: [{root: runs/smoke/scenes, weight: 1.0}]
  height: 48
  width: 80
  input_frames: 9
  target_views: 4
  unseen_fraction: 0.5
  batch_size: 1
  workers: 1
  latents: true
model:
  vae: {dim: 8}
  heads: independent
raster:
  window: flat
  eps: 0.1
loss:
  lambda_perc: 0.0      # no LPIPS weights in the smoke run (training refuses to run without them when > 0)
  lambda_opacity: 0.001
)";

double item(const at::Tensor& t) { return t.detach().to(at::kDouble).cpu().item<double>(); }

int run(const SmokeConfig& cfg, const std::string& effective_yaml) {
  auto run = RunDir::create(cfg.run_dir);
  setup_logging("info", run.log_file());
  config::save_text(run.config_file(), effective_yaml);
  spdlog::info("flat_smoke: run folder {}, effective config saved to {}", run.root, run.config_file());

  at::Device device(cfg.device == "cuda" ? at::kCUDA : at::kCPU);
  if (device.is_cuda() && !torch::cuda::is_available()) fail("device: cuda requested but no CUDA device is available");
  torch::manual_seed(static_cast<uint64_t>(cfg.seed));

  data::Loader loader(cfg.data);
  model::SceneDecoder decoder(cfg.model, cfg.triangles.channels());  // heads sized for the triangle layout
  decoder->to(device);
  loss::Objective objective(cfg.loss, device);
  torch::optim::AdamW optimiser(decoder->parameters(),
                                torch::optim::AdamWOptions(cfg.lr).weight_decay(cfg.weight_decay));
  int64_t params = 0;
  for (const auto& p : decoder->parameters()) params += p.numel();
  spdlog::info("scene decoder: {} parameters (dim {}), {} heads", params, cfg.model.vae.dim, cfg.model.heads);

  nlohmann::json history = nlohmann::json::array();
  Progress progress("flat_smoke", cfg.steps, 5.0);
  render::RenderOutput last;
  primitives::TriangleSoup last_soup;
  camera::CameraSet last_views;
  for (int64_t step = 0; step < cfg.steps; ++step) {
    data::Batch batch = loader.next();
    const int64_t B = batch.video_latents.size(0);
    auto latents = batch.video_latents.to(device, at::kFloat);
    auto camera_latents = batch.camera_latents.defined() ? batch.camera_latents.to(device, at::kFloat) : at::Tensor();
    auto raw = decoder->forward(latents, camera_latents);  // (B,C,T,H/2,W/2)
    const int64_t T = raw.size(2), image_h = raw.size(3) * 2, image_w = raw.size(4) * 2;
    FLAT_CHECK(T == batch.input_intrinsics.size(1),
               "decoded " + std::to_string(T) + " frames but the window has " +
                   std::to_string(batch.input_intrinsics.size(1)) + " cameras");
    camera::Cameras anchors{batch.input_intrinsics.reshape({B * T, 4}).to(device),
                            batch.input_c2w.reshape({B * T, 4, 4}).to(device)};
    auto soup = primitives::build_triangles(raw, anchors, image_h, image_w, cfg.triangles);

    at::Tensor total = at::zeros({}, raw.options());
    std::map<std::string, double> terms;
    for (int64_t b = 0; b < B; ++b) {
      auto scene = soup.scene(b);
      auto targets = batch.target_cameras(b).to(device);
      const int64_t H = batch.target_images.size(3), W = batch.target_images.size(4);
      auto out = render::rasterize(scene.vertices, scene.colors, scene.opacities, scene.sigmas, targets, H, W,
                                   cfg.raster);
      loss::LossInputs in;
      in.rgb = out.rgb;
      in.target_rgb = batch.target_images[b].to(device);
      in.alpha = out.alpha;
      // The rasterizer's depth and normal are alpha-weighted sums: normalise
      // by alpha to compare with the targets.
      auto a = out.alpha.clamp_min(1e-6);
      in.depth = out.depth / a;
      in.normal = out.normal;
      if (batch.target_depth.defined() && batch.depth_present[b].item<bool>())
        in.target_depth = batch.target_depth[b].to(device);
      if (batch.target_normals.defined() && batch.normals_present[b].item<bool>())
        in.target_normal = batch.target_normals[b].to(device);
      in.opacities = scene.opacities;
      in.intrinsics = targets.intrinsics;
      auto result = objective(in);
      total = total + result.total / double(B);
      for (const auto& [name, value] : result.terms) terms[name] += item(value) / double(B);
      if (b == 0) {
        last = out;
        last_views.cameras = batch.target_cameras(b);
        last_views.width = W;
        last_views.height = H;
      }
    }
    if (!std::isfinite(item(total))) fail("step " + std::to_string(step) + ": the loss is not finite");
    optimiser.zero_grad();
    total.backward();
    optimiser.step();

    nlohmann::json row = {{"step", step}, {"loss", item(total)}};
    for (const auto& [name, value] : terms) row[name] = value;
    history.push_back(row);
    progress.step(1, {{"loss", item(total)}, {"rgb", terms.count("rgb") ? terms["rgb"] : 0.0}});
    last_soup = soup;
  }
  progress.finish();

  write_file_atomic(run.metrics() + "/smoke.json", history.dump(2) + "\n");
  save_safetensors(run.renders() + "/final.safetensors",
                   {{"rgb", last.rgb.detach().cpu()}, {"alpha", last.alpha.detach().cpu()},
                    {"depth", last.depth.detach().cpu()}, {"normal", last.normal.detach().cpu()}},
                   {{"producer", "flat_smoke"}, {"steps", std::to_string(cfg.steps)}});
  auto scene0 = last_soup.scene(0);
  exporter::write_triangle_ply(run.root + "/triangles.ply",
                               {scene0.vertices.detach().cpu().to(at::kFloat),
                                scene0.colors.detach().cpu().to(at::kFloat),
                                scene0.opacities.detach().cpu().to(at::kFloat),
                                scene0.sigmas.detach().cpu().to(at::kFloat)});
  // The target cameras of the final render, so that flat_render can re-render triangles.ply.
  camera::write_cameras_json(run.root + "/cameras.json", last_views);
  const double first = history.front()["loss"], final = history.back()["loss"];
  spdlog::info("flat_smoke: {} steps, loss {:.5f} -> {:.5f}; {} triangles per scene; outputs in {}", cfg.steps, first,
               final, scene0.vertices.size(0), run.root);
  if (loader.skipped_scenes() > 0) spdlog::warn("skipped {} bad scene(s)", loader.skipped_scenes());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"flat_smoke: a few optimisation steps through the whole FLAT pipeline (README command 1)"};
  std::string config_file;
  std::vector<std::string> overrides;
  bool print_config = false;
  app.add_option("--config", config_file, "YAML config (default: the embedded tiny config)");
  app.add_option("--set", overrides, "override a key: --set steps=10 --set data.height=64")->take_all();
  app.add_flag("--print-config", print_config, "print the effective config and exit");
  CLI11_PARSE(app, argc, argv);
  try {
    SmokeConfig cfg = config_file.empty() ? flat::config::parse<SmokeConfig>(kDefaultConfig, "<embedded default>", overrides)
                                          : flat::config::load<SmokeConfig>(config_file, overrides);
    cfg.data.check();
    cfg.raster.check();
    cfg.triangles.validate();
    const std::string yaml = flat::config::to_yaml(cfg);
    if (print_config) {
      std::cout << yaml;
      return 0;
    }
    return run(cfg, yaml);
  } catch (...) {
    return flat::report_current_error();
  }
}
