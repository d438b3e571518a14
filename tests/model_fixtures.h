// Test fixtures for flat_infer and flat_eval: a tiny random-weight decoder
// saved as a model file, and synthetic scenes with (random) latents, made
// through the library (no processes, no pretrained weights).
#pragma once
#include <filesystem>
#include <string>
#include <vector>

#include <torch/torch.h>

#include "flat/core/config.h"
#include "flat/data/scene_latents.h"
#include "flat/data/synthetic_scene.h"
#include "flat/model/weights.h"
#include "flat/pipeline/trained_model.h"

namespace flat::test {

// A dim-8 scene decoder (the tiny training config's) with the depth range of
// the synthetic rooms.
inline pipeline::PipelineConfig tiny_pipeline_config(int64_t dim = 8) {
  return config::from_yaml<pipeline::PipelineConfig>(
      config::load_yaml_text("model: {vae: {dim: " + std::to_string(dim) + "}}\ntriangles: {depth_far: 12.0}\n",
                             "<tiny pipeline>"),
      "<tiny pipeline>");
}

// Saves a seeded random decoder to `path` with its signature and config, as
// flat_train does. Returns the config.
inline pipeline::PipelineConfig write_tiny_model(const std::string& path, int64_t dim = 8, uint64_t seed = 1,
                                                 bool with_config_metadata = true) {
  auto cfg = tiny_pipeline_config(dim);
  torch::manual_seed(seed);
  model::SceneDecoder decoder(cfg.model, cfg.triangles.channels());
  auto sig = pipeline::model_signature(cfg);
  if (!with_config_metadata) sig.pipeline_config.clear();
  auto meta = pipeline::signature_metadata(sig);
  meta["stage"] = "test";
  meta["step"] = "0";
  model::save_weights(*decoder, path, model::WeightNaming::wan, meta);
  return cfg;
}

// A synthetic room of `frames` frames at 48x80 with exact depth and normals
// and one latent window over its first `window` frames (random latents of the
// right shapes: the pipeline does not care where latents come from).
inline data::Scene write_scene_with_latents(const std::string& dir, uint64_t seed, int64_t frames = 13,
                                            int64_t window = 9) {
  data::SynthOptions o;
  o.frames = frames;
  o.height = 48;
  o.width = 80;
  o.seed = seed;
  o.motion = "pan";
  auto synth = data::render_synthetic_scene(o);
  auto scene = data::write_synthetic_scene(synth, dir, std::filesystem::path(dir).filename().string(), "synthetic");
  data::LatentInfo info;
  info.encoder = "random";
  info.height = 48;
  info.width = 80;
  info.windows = {{0, window}};
  const int64_t Tl = 1 + (window - 1) / 4;
  torch::manual_seed(seed + 100);
  data::WindowLatents l{torch::randn({16, Tl, 6, 10}), torch::randn({32, Tl, 6, 10})};
  data::write_scene_latents(scene, info, {l});
  return data::read_scene(dir);
}

// write_scene_with_latents() for each of `scenes` (folders below `dir`, e.g.
// "setA/room_a"), with seeds 1, 2, ... in their order.
inline void write_scenes_with_latents(const std::filesystem::path& dir, const std::vector<std::string>& scenes) {
  for (size_t i = 0; i < scenes.size(); ++i) write_scene_with_latents((dir / scenes[i]).string(), uint64_t(i + 1));
}

}  // namespace flat::test
