// A trained scene decoder as flat_infer, flat_eval and the trainer's
// `init.from: checkpoint` find it: a run folder (its model.safetensors, else
// its newest checkpoint), a checkpoint folder, or a model .safetensors file.
//
// A model file carries, in its safetensors metadata, the architecture
// signature ("model_signature": the keys that must agree for the weights to
// fit) and the whole pipeline config ("pipeline_config", YAML), so it can be
// used without the run folder it came from. Files written before
// "pipeline_config" existed find it in the checkpoint's trainer.json or the
// run's config.yaml beside them; --config supplies it otherwise.
#pragma once
#include <map>
#include <string>
#include <vector>

#include <torch/nn/module.h>

#include "flat/core/tensor_io.h"
#include "flat/model/scene_decoder.h"
#include "flat/pipeline/scene_pipeline.h"

namespace flat::pipeline {

// The architecture keys of a pipeline config that must agree between a model
// file and the model it is loaded into, plus the whole config for readers.
struct ModelSignature {
  std::string yaml;             // "pipeline.model.vae.dim: 96\n..." one key per line
  std::string pipeline_config;  // the pipeline section as YAML ("" when unknown)
};

ModelSignature model_signature(const PipelineConfig& config);
// The metadata a model file is written with (producer, stage, step added by the caller).
std::map<std::string, std::string> signature_metadata(const ModelSignature& signature);

// Loads weights into `model`, checking first that the file's signature (when
// it has one) equals `expected`; the error lists the keys that differ.
void load_model_weights(torch::nn::Module& model, const TensorMap& tensors, const ModelSignature& found,
                        const ModelSignature& expected, const std::string& label);

// A run folder, a checkpoint folder or a model file -> the model file to read.
// Read-only: never removes anything (a crashed checkpoint write is ignored).
std::string resolve_model_file(const std::string& path);

struct TrainedModel {
  PipelineConfig config;
  model::SceneDecoder decoder{nullptr};
  std::string model_file;
  std::string config_source;  // where the pipeline config came from
  std::string stage, step;    // from the file's metadata ("" when absent)
  std::string describe() const;  // "runs/x/model.safetensors (stage stage1, step 300)"
};

// path: run folder | checkpoint folder | model file. config_file: optional
// YAML with pipeline keys (a training config's `pipeline:` section, or the
// section itself), layered over the config the model carries (or used alone
// for a model that carries none).
// overrides: "key=value" relative to the pipeline section ("prune_opacity=0.4",
// "raster.window=ts"); an override that changes the architecture fails the
// signature check. The decoder is in eval mode on the CPU.
TrainedModel load_trained_model(const std::string& path, const std::string& config_file = "",
                                const std::vector<std::string>& overrides = {});

}  // namespace flat::pipeline
