// flat_infer: decode precomputed latents into a triangle scene with a trained
// decoder, then export and render it (src/infer/inference.h lists the outputs).
//
//   flat_infer --model runs/stage1 --scene data/val/room_000001 --out out/room1
//   flat_infer --model model.safetensors --latents z.safetensors --cameras traj.json --out out/gen
//
// Exit codes: 0 done, 1 runtime error (message names the file, key or shape),
// 2 usage error.
#include <filesystem>
#include <iostream>

#include <CLI/CLI.hpp>

#include "flat/core/cli.h"
#include "flat/core/cli_model_options.h"
#include "flat/core/config.h"
#include "flat/core/error.h"
#include "flat/core/log.h"
#include "flat/infer/inference.h"
#include "flat/pipeline/scene_pipeline.h"

int main(int argc, char** argv) {
  CLI::App app{"flat_infer: latents -> triangle scene (PLY, GLB), renders, videos and a browser viewer"};
  app.get_formatter()->column_width(36);
  flat::infer::InferOptions o;
  flat::cli::add_common(app, "flat_infer", o.log_level);
  std::string size, novel = "orbit";
  bool full_sequence = false, no_ply = false, no_glb = false, no_renders = false, no_video = false, no_viewer = false;
  app.add_option("--model", o.model, "run folder, checkpoint folder or model .safetensors")->required();
  app.add_option("--scene", o.input.scene_dir, "scene folder with precomputed latents (flat_latents)");
  app.add_option("--window-index", o.input.window, "which stored latent window of --scene (0: the first)")
      ->capture_default_str();
  flat::cli::add_old_name(app, "--window", "--window-index");
  app.add_option("--latent-set", o.input.latent_set,
                 "which latent set of --scene, HxW_fF (e.g. 176x320_f17; default: the scene's only set)");
  app.add_option("--latents", o.input.latents_file, "latent file: 'video' (16,T',h,w) [+ 'camera' (32,T',h,w)]");
  app.add_option("--cameras", o.input.cameras_file, "the latents' trajectory: cameras JSON with 1+4(T'-1) cameras");
  app.add_option("--vae", o.input.vae_weights,
                 "Wan 2.1 VAE weights (.safetensors or a diffusers folder), to encode camera latents the latent file "
                 "lacks");
  app.add_option("--out", o.out_dir,
                 "output folder (must not exist unless --overwrite); built in <out>.incomplete-<pid>, which a killed "
                 "run leaves and the next run on the same --out removes")
      ->required();
  app.add_flag("--overwrite", o.overwrite, "replace an existing output folder (only once the new one is complete)");
  int threads = 0;
  flat::cli::add_model_options(app, o.config, o.overrides, "pipeline.raster.window=ts", o.device, threads,
                               o.precision);
  app.add_flag("--full-sequence", full_sequence, "decode all latent frames at once (default: streaming, bounded memory)");
  app.add_option("--prune-opacity", o.prune_opacity,
                 "drop triangles below this opacity (default: the model's pipeline.prune_opacity, the threshold it was "
                 "trained with, e.g. 0.4 at stage 4; 0.05 for a model trained without pruning)");
  app.add_option("--novel", novel, "novel trajectory: orbit | dolly | none | a cameras JSON file")->capture_default_str();
  app.add_option("--novel-frames", o.novel.frames, "views of an orbit/dolly preset")->capture_default_str();
  app.add_option("--orbit-degrees", o.novel.degrees, "orbit: half the sweep")->capture_default_str();
  app.add_option("--dolly-fraction", o.novel.fraction, "dolly: share of the look-at distance")->capture_default_str();
  app.add_option("--size", size, "render size HxW (default: the input frames')");
  app.add_option("--render-chunk", o.render_chunk, "views per rasterizer call")->capture_default_str();
  app.add_option("--fps", o.fps, "video frame rate")->capture_default_str();
  app.add_option("--three-js", o.three_js_dir, "three.js folder for the viewer (default: Debian's libjs-three)");
  app.add_flag("--no-ply", no_ply, "skip scene.ply");
  app.add_flag("--no-glb", no_glb, "skip scene.glb (and the viewer)");
  app.add_flag("--no-renders", no_renders, "skip the per-view image files");
  app.add_flag("--no-video", no_video, "skip the MP4 videos");
  app.add_flag("--no-viewer", no_viewer, "skip the browser viewer");
  if (int rc = flat::cli::parse(app, argc, argv); rc >= 0) return rc;
  flat::cli::apply_threads(threads);
  return flat::cli::run([&] {
    flat::setup_logging(o.log_level);
    // Full key paths, as flat_train's; the model's config is the pipeline section.
    o.overrides = flat::cli::section_overrides(o.overrides, "pipeline",
                                               flat::config::to_yaml(flat::pipeline::PipelineConfig{}), "flat_infer");
    o.streaming = !full_sequence;
    o.novel.preset = novel;
    o.ply = !no_ply;
    o.glb = !no_glb;
    o.renders = !no_renders;
    o.video = !no_video;
    o.viewer = !no_viewer && !no_glb;
    // Contradictory or missing inputs are usage errors (exit 2), found before any work.
    if (o.input.scene_dir.empty() == o.input.latents_file.empty()) {
      std::cerr << "flat_infer: give exactly one of --scene FOLDER or --latents FILE (with --cameras FILE)\n";
      return 2;
    }
    if (!o.input.latents_file.empty() && o.input.cameras_file.empty()) {
      std::cerr << "flat_infer: --latents needs --cameras FILE (the trajectory of the latents' frames)\n";
      return 2;
    }
    if (novel != "orbit" && novel != "dolly" && novel != "none" && !std::filesystem::is_regular_file(novel)) {
      std::cerr << "flat_infer: --novel '" << novel << "': expected orbit | dolly | none or a cameras JSON file "
                   "(no such file)\n";
      return 2;
    }
    flat::cli::parse_size_option(size, o.height, o.width, "flat_infer");
    auto summary = flat::infer::run_inference(o);
    std::cout << flat::infer::format_summary(summary);
    return 0;
  });
}
