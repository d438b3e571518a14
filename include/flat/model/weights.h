// Loading and saving module weights as safetensors, with either key naming
// (weight_names.h). Strict by default: every parameter of the module must come
// from the file with the right shape and no file tensor may be left over; all
// problems are listed in ONE flat::Error (missing, unexpected, wrong shape).
// Partial loading is explicit through LoadSpec.
#pragma once
#include <string>
#include <vector>

#include <torch/nn/module.h>

#include "flat/core/tensor_io.h"
#include "flat/model/weight_names.h"

namespace flat::model {

struct LoadSpec {
  // File tensors (wan names) to use: those under any of these prefixes; empty = all.
  // Tensors outside `take` are ignored on purpose (e.g. the encoder when only the
  // decoder is wanted) and reported as skipped.
  std::vector<std::string> take;
  // Module parameters under these prefixes may be absent from the file and keep
  // their initialisation (e.g. a fresh camera adapter and heads).
  std::vector<std::string> keep_initialised;
  // Strip this prefix from file keys before matching (e.g. "vae." for a bundle).
  std::string file_prefix;
  // Stripped from every file key before the naming is detected (weights saved by
  // other tools, e.g. "vae."). "" = detected: a dotted prefix that every key
  // carries and no module parameter starts with (logged in one line); detected
  // only when neither file_prefix nor take is set.
  std::string strip_prefix;
};

struct LoadReport {
  std::string file;
  WeightNaming naming = WeightNaming::wan;
  std::vector<std::string> loaded;       // module names set from the file
  std::vector<std::string> initialised;  // module names kept as initialised (allowed by the spec)
  std::vector<std::string> skipped;      // file names outside `take`
  std::string summary() const;           // one line for logs
};

// Copies the file's tensors into `module` (keeping each parameter's dtype and
// device). Throws flat::Error naming `label` with every missing, unexpected and
// wrong-shape tensor; nothing is modified when it throws.
LoadReport load_state(torch::nn::Module& module, const TensorMap& tensors, const LoadSpec& spec,
                      const std::string& label);
// Reads `path` (safetensors, either naming, detected) and calls load_state.
// `path` may be a folder as diffusers saves one: its
// diffusion_pytorch_model.safetensors (or model.safetensors, or its only
// .safetensors file) is read.
LoadReport load_weights(torch::nn::Module& module, const std::string& path, const LoadSpec& spec = {});

// The weights file inside a diffusers-style folder (or `path` itself when it is
// a file); throws naming the folder when there is no single candidate.
std::string resolve_weights_file(const std::string& path);

// The module's parameters as CPU tensors under the chosen naming.
TensorMap state_tensors(const torch::nn::Module& module, WeightNaming naming = WeightNaming::wan);
// Writes them (atomic) with metadata {"format": "flat", "naming": ...} plus `metadata`.
void save_weights(const torch::nn::Module& module, const std::string& path, WeightNaming naming = WeightNaming::wan,
                  const Metadata& metadata = {});

// Number of scalar parameters (optionally only those under `prefix`).
int64_t count_parameters(const torch::nn::Module& module, const std::string& prefix = "");

// Re-lays every 5-D parameter out as ChannelsLast3d (for cuDNN's NDHWC kernels).
void to_channels_last_3d(torch::nn::Module& module);

}  // namespace flat::model
