// Finding and loading a trained decoder: run folder, checkpoint folder, model
// file; the pipeline config from the file's metadata or from beside it; clear
// errors for another architecture or a file that says nothing.
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "flat/pipeline/trained_model.h"
#include "model_fixtures.h"
#include "test_support.h"

namespace fs = std::filesystem;
using namespace flat;

TEST_CASE("a model file carries its pipeline config and loads to the same weights", "[pipeline]") {
  const auto dir = test::scratch_dir("trained_model_file");
  const std::string file = (dir / "model.safetensors").string();
  auto cfg = test::write_tiny_model(file, 8, 7);
  auto m = pipeline::load_trained_model(file);
  CHECK(m.config.model.vae.dim == 8);
  CHECK(m.config.triangles.depth_far == 12.0);
  CHECK(m.config_source.find("metadata") != std::string::npos);
  CHECK(m.stage == "test");
  torch::manual_seed(7);
  model::SceneDecoder fresh(cfg.model, cfg.triangles.channels());
  auto a = m.decoder->named_parameters(), b = fresh->named_parameters();
  REQUIRE(a.size() == b.size());
  for (const auto& p : a) CHECK(at::equal(p.value(), b[p.key()]));
  CHECK(!m.decoder->is_training());
  // Overrides apply to the pipeline section.
  auto o = pipeline::load_trained_model(file, "", {"prune_opacity=0.25", "raster.window=ts"});
  CHECK(o.config.prune_opacity == 0.25);
  CHECK(o.config.raster.window == "ts");
  // An override that changes the architecture fails the signature check.
  REQUIRE_THROWS_WITH(pipeline::load_trained_model(file, "", {"model.vae.dim=16"}),
                      FLAT_CONTAINS("pipeline.model.vae.dim: checkpoint 8, this config 16"));
}

TEST_CASE("run and checkpoint folders resolve to their model file; older files find their config", "[pipeline]") {
  const auto run = test::scratch_dir("trained_model_run");
  fs::create_directories(run / "checkpoints/step_00000010");
  fs::create_directories(run / "checkpoints/step_00000020");
  fs::create_directories(run / "checkpoints/.incomplete-step_00000030.1");
  test::write_tiny_model((run / "checkpoints/step_00000010/model.safetensors").string(), 8, 1, false);
  test::write_tiny_model((run / "checkpoints/step_00000020/model.safetensors").string(), 8, 2, false);
  for (auto step : {"10", "20"}) {
    std::ofstream(run / (std::string("checkpoints/step_000000") + step) / "trainer.json")
        << nlohmann::json{{"config", "pipeline:\n  model: {vae: {dim: 8}}\n  triangles: {depth_far: 9.0}\n"}}.dump();
  }
  // No model.safetensors at the root: the newest complete checkpoint.
  CHECK(pipeline::resolve_model_file(run.string()) == (run / "checkpoints/step_00000020/model.safetensors").string());
  CHECK(fs::exists(run / "checkpoints/.incomplete-step_00000030.1"));  // read-only: nothing removed
  auto m = pipeline::load_trained_model(run.string());
  CHECK(m.config.triangles.depth_far == 9.0);  // from trainer.json (the file has no pipeline_config)
  CHECK(m.config_source.find("trainer.json") != std::string::npos);

  // A bare older file with nothing beside it.
  const auto lone = test::scratch_dir("trained_model_lone");
  test::write_tiny_model((lone / "m.safetensors").string(), 8, 1, false);
  REQUIRE_THROWS_WITH(pipeline::load_trained_model((lone / "m.safetensors").string()),
                      FLAT_CONTAINS("m.safetensors") && FLAT_CONTAINS("--config"));
  // ...works with --config.
  std::ofstream(lone / "c.yaml") << "pipeline:\n  model: {vae: {dim: 8}}\n";
  CHECK(pipeline::load_trained_model((lone / "m.safetensors").string(), (lone / "c.yaml").string()).config.model.vae.dim ==
        8);
  REQUIRE_THROWS_WITH(pipeline::load_trained_model((lone / "missing").string()), FLAT_CONTAINS("missing"));
}

TEST_CASE("--config layers over the config the model carries", "[pipeline]") {
  const auto dir = test::scratch_dir("trained_model_layer");
  const std::string file = (dir / "model.safetensors").string();
  test::write_tiny_model(file);  // carries depth_far 12
  std::ofstream(dir / "window.yaml") << "pipeline:\n  raster: {window: ts}\n";
  auto m = pipeline::load_trained_model(file, (dir / "window.yaml").string());
  CHECK(m.config.raster.window == "ts");            // from the file
  CHECK(m.config.triangles.depth_far == 12.0);      // kept from the model
  CHECK(m.config_source.find("window.yaml") != std::string::npos);
}

TEST_CASE("kernel choices are config keys that reach the loaded decoder and leave the signature alone",
          "[pipeline]") {
  const auto dir = test::scratch_dir("trained_model_kernels");
  const std::string file = (dir / "model.safetensors").string();
  test::write_tiny_model(file);  // trained with the default kernels
  std::ofstream(dir / "kernels.yaml")
      << "pipeline:\n  model:\n    kernels: {fused_norm: false, subpixel_upsample: false, conv_backend: cudnn}\n";
  auto m = pipeline::load_trained_model(file, (dir / "kernels.yaml").string());
  CHECK_FALSE(m.config.model.kernels.fused_norm);
  CHECK_FALSE(m.config.model.kernels.subpixel_upsample);
  CHECK(m.config.model.kernels.conv_backend == "cudnn");
  // The decoder was built with them: its modules hold them.
  CHECK_FALSE(m.decoder->decoder->mid1->norm1->fused());
  CHECK(m.decoder->decoder->conv1->conv_backend() == "cudnn");
  CHECK(m.decoder->heads->convs[0]->conv_backend() == "cudnn");
  CHECK_FALSE(m.decoder->decoder->up_resample[0]->subpixel_upsample());
  // Speed only: the signature is that of the defaults.
  CHECK(pipeline::model_signature(m.config).yaml == pipeline::model_signature(test::tiny_pipeline_config()).yaml);
  // An unknown backend names the key, wherever it is given.
  std::ofstream(dir / "bad.yaml") << "pipeline:\n  model:\n    kernels: {conv_backend: fastest}\n";
  REQUIRE_THROWS_WITH(pipeline::load_trained_model(file, (dir / "bad.yaml").string()),
                      FLAT_CONTAINS("'model.kernels.conv_backend': expected one of {auto, cudnn") &&
                          FLAT_CONTAINS("'fastest'"));
  REQUIRE_THROWS_WITH(pipeline::load_trained_model(file, "", {"model.kernels.conv_backend=fastest"}),
                      FLAT_CONTAINS("kernels.conv_backend"));
}

TEST_CASE("the model signature names the ablations that change what the weights mean", "[pipeline]") {
  pipeline::PipelineConfig p;
  const std::string paper = pipeline::model_signature(p).yaml;
  CHECK(paper.find("camera_rays") == std::string::npos);  // older files stay valid
  CHECK(paper.find("representation") == std::string::npos);
  p.model.adapter_zero_init = false;  // an initialisation: the weights mean the same
  CHECK(pipeline::model_signature(p).yaml == paper);
  p.model.camera_rays = "plucker";
  CHECK(pipeline::model_signature(p).yaml.find("pipeline.model.camera_rays: plucker") != std::string::npos);
  pipeline::PipelineConfig g;
  g.representation = "3dgs";
  CHECK(pipeline::model_signature(g).yaml.find("pipeline.representation: 3dgs") != std::string::npos);
  CHECK(g.channels().total == 12);
  g.representation = "2dgs";
  CHECK(g.channels().total == 11);
}
