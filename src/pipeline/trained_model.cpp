#include "flat/pipeline/trained_model.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>
#include <yaml-cpp/yaml.h>

#include "flat/core/config.h"
#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/model/weights.h"

namespace flat::pipeline {
namespace fs = std::filesystem;

namespace {

// "key: value" lines -> map, for the signature comparison.
std::map<std::string, std::string> signature_lines(const std::string& yaml) {
  std::map<std::string, std::string> out;
  std::istringstream in(yaml);
  for (std::string line; std::getline(in, line);) {
    const auto colon = line.find(": ");
    if (colon != std::string::npos) out[line.substr(0, colon)] = line.substr(colon + 2);
  }
  return out;
}

// Newest complete checkpoint folder (step_* holding trainer.json), "" if none.
std::string newest_checkpoint(const fs::path& checkpoints) {
  std::error_code ec;
  if (!fs::is_directory(checkpoints, ec)) return "";
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(checkpoints, ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind("step_", 0) == 0 && e.is_directory() && fs::exists(e.path() / "trainer.json")) names.push_back(name);
  }
  if (names.empty()) return "";
  std::sort(names.begin(), names.end());  // step_%08d: text order is step order
  return (checkpoints / names.back()).string();
}

std::string read_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path.string() + ": cannot open for reading");
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// A training config's `pipeline:` section, or the whole node when it has none.
YAML::Node pipeline_section(const YAML::Node& root) {
  if (root.IsMap() && root["pipeline"]) return root["pipeline"];
  return root;
}

// Where an older model file's config lives: the checkpoint's trainer.json
// beside it, or the run's config.yaml (beside it, or two folders up for
// <run>/checkpoints/step_*/model.safetensors).
bool config_near(const fs::path& model_file, YAML::Node& node, std::string& source) {
  const fs::path dir = model_file.parent_path();
  std::error_code ec;
  if (fs::exists(dir / "trainer.json", ec)) {
    try {
      auto j = nlohmann::json::parse(read_text(dir / "trainer.json"));
      node = pipeline_section(config::load_yaml_text(j.at("config").get<std::string>(), (dir / "trainer.json").string()));
      source = (dir / "trainer.json").string();
      return true;
    } catch (const nlohmann::json::exception& e) {
      fail((dir / "trainer.json").string() + ": not a valid checkpoint record (" + e.what() + ")");
    }
  }
  for (const fs::path& candidate : {dir / "config.yaml", dir.parent_path().parent_path() / "config.yaml"}) {
    if (fs::exists(candidate, ec)) {
      node = pipeline_section(config::load_yaml_file(candidate.string()));
      source = candidate.string();
      return true;
    }
  }
  return false;
}

// A decoder of another width (pipeline.model.vae.dim): both widths first, read
// from the decoder's first conv (dim * dim_mult.back() outputs), instead of a
// list of a hundred wrong shapes that never says which width either side has.
void check_decoder_width(const TensorMap& tensors, const model::SceneDecoder& decoder,
                         const model::WanVAEConfig& vae, const std::string& label, const std::string& config_source) {
  const std::string name = "decoder.conv1.weight";
  const auto params = decoder->named_parameters(/*recurse=*/true);
  const at::Tensor* mine = params.find(name);
  auto theirs = tensors.find(name);
  if (theirs == tensors.end()) theirs = tensors.find("decoder.conv_in.weight");  // diffusers naming
  if (mine == nullptr || theirs == tensors.end() || theirs->second.dim() != mine->dim() ||
      theirs->second.size(0) == mine->size(0))
    return;
  const int64_t mult = vae.dim_mult.empty() ? 1 : vae.dim_mult.back(), outputs = theirs->second.size(0);
  const std::string file_dim = outputs % mult == 0 ? "dim " + std::to_string(outputs / mult)
                                                   : "another width (not a multiple of " + std::to_string(mult) + ")";
  fail(label + ": the file's decoder has " + file_dim + " but this config's has dim " + std::to_string(vae.dim) +
       " (pipeline.model.vae.dim; " + theirs->first + " is " + shape_str(theirs->second) + " in the file, " +
       shape_str(*mine) + " in this config's model; the config: " + (config_source.empty() ? "defaults" : config_source) +
       "). Give the model's training config with --config, or set pipeline.model.vae.dim to the file's width");
}

}  // namespace

ModelSignature model_signature(const PipelineConfig& p) {
  config::Describer d("pipeline.model.");
  auto model = p.model;
  model.visit(d);
  std::string yaml;
  for (const auto& row : d.rows)
    // Keys that change how the decoder runs, not its weights (the kernel
    // choices included), stay out, and so does the initialisation; the
    // ablations' camera rays enter only when not the paper's (older
    // signatures stay valid).
    if (row.key != "pipeline.model.stream_trunk_frames" && row.key != "pipeline.model.activation_checkpointing" &&
        row.key != "pipeline.model.adapter_zero_init" && row.key.rfind("pipeline.model.kernels.", 0) != 0 &&
        !(row.key == "pipeline.model.camera_rays" && row.value == "rppc"))
      yaml += row.key + ": " + row.value + "\n";
  // Triangle models keep the signature they always had; the Gaussian
  // baselines name their representation (3DGS and triangles both have 12).
  if (p.representation != primitives::kTriangles) yaml += "pipeline.representation: " + p.representation + "\n";
  yaml += "pipeline.triangles.channels: " + std::to_string(p.channels().total) + "\n";
  return {yaml, config::to_yaml(p)};
}

std::map<std::string, std::string> signature_metadata(const ModelSignature& s) {
  std::map<std::string, std::string> m{{"model_signature", s.yaml}};
  if (!s.pipeline_config.empty()) m["pipeline_config"] = s.pipeline_config;
  return m;
}

void load_model_weights(torch::nn::Module& model, const TensorMap& tensors, const ModelSignature& found,
                        const ModelSignature& expected, const std::string& label) {
  if (!found.yaml.empty() && found.yaml != expected.yaml) {
    auto a = signature_lines(found.yaml), b = signature_lines(expected.yaml);
    std::string diff;
    for (const auto& [k, v] : b) {
      auto it = a.find(k);
      const std::string theirs = it == a.end() ? "(absent)" : it->second;
      if (theirs != v) diff += "\n  " + k + ": checkpoint " + theirs + ", this config " + v;
    }
    for (const auto& [k, v] : a)
      if (!b.count(k)) diff += "\n  " + k + ": checkpoint " + v + ", this config (absent)";
    fail(label + ": the checkpoint's model differs from this config's:" + diff);
  }
  model::load_state(model, tensors, {}, label);
}

std::string resolve_model_file(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(path, ec))
    fail(path + ": not found (expected a run folder, a checkpoint folder or a model .safetensors file)");
  if (fs::is_regular_file(path, ec)) return path;
  if (fs::exists(fs::path(path) / "model.safetensors", ec)) return path + "/model.safetensors";
  const std::string latest = newest_checkpoint(fs::path(path) / "checkpoints");
  if (latest.empty()) fail(path + ": a folder without model.safetensors or any checkpoint under checkpoints/");
  return latest + "/model.safetensors";
}

std::string TrainedModel::describe() const {
  std::string s = model_file;
  if (!stage.empty() || !step.empty()) s += " (stage " + (stage.empty() ? "?" : stage) + ", step " + step + ")";
  return s;
}

TrainedModel load_trained_model(const std::string& path, const std::string& config_file,
                                const std::vector<std::string>& overrides) {
  TrainedModel m;
  m.model_file = resolve_model_file(path);
  Metadata meta;
  auto tensors = load_safetensors(m.model_file, &meta);
  // The weights themselves, named with the file before anything is decoded
  // with them (a NaN weight would otherwise surface as NaN triangles of
  // every scene, blaming the scene).
  for (const auto& [key, t] : tensors) {
    if (!t.is_floating_point())
      fail(m.model_file + ": '" + key + "' has dtype " + std::string(c10::toString(t.scalar_type())) +
           "; model weights must be floating point");
    check_finite(t, m.model_file + ": weight '" + key + "'");
  }
  if (meta.count("stage")) m.stage = meta["stage"];
  if (meta.count("step")) m.step = meta["step"];

  // The model's own config, with a --config file layered over it (keys the
  // file gives replace the model's; an architecture change fails below).
  YAML::Node node;
  if (meta.count("pipeline_config")) {
    node = config::load_yaml_text(meta["pipeline_config"], m.model_file + " (metadata 'pipeline_config')");
    m.config_source = m.model_file + " (metadata)";
  } else if (!config_near(fs::path(m.model_file), node, m.config_source) && config_file.empty()) {
    fail(m.model_file + ": the file does not say which pipeline config it was trained with (no 'pipeline_config' "
         "metadata, no trainer.json or config.yaml beside it); give the training config with --config");
  }
  if (!config_file.empty()) {
    auto overlay = pipeline_section(config::load_yaml_file(config_file));
    node = node.IsDefined() && !node.IsNull() ? config::merge(node, overlay) : overlay;
    m.config_source = m.config_source.empty() ? config_file : m.config_source + " + " + config_file;
  }
  node = YAML::Clone(node);
  config::apply_overrides(node, overrides, "--set");
  m.config = config::from_yaml<PipelineConfig>(node, m.config_source);

  m.decoder = model::SceneDecoder(m.config.model, m.config.channels());
  const ModelSignature found{meta.count("model_signature") ? meta["model_signature"] : "", ""};
  if (found.yaml.empty()) check_decoder_width(tensors, m.decoder, m.config.model.vae, m.model_file, m.config_source);
  load_model_weights(*m.decoder, tensors, found, model_signature(m.config), m.model_file);
  m.decoder->eval();
  return m;
}

}  // namespace flat::pipeline
