// The options of a tool that runs a trained model's pipeline (flat_eval,
// flat_infer): one helper, so the two tools spell and explain them alike.
#pragma once
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

namespace flat::cli {

// In this order: --config (pipeline keys layered over the config the model
// carries), --set KEY=VALUE (`set_example` shown in --help), --device,
// --threads, and --precision (bf16 applies on CUDA only).
void add_model_options(CLI::App& app, std::string& config, std::vector<std::string>& overrides,
                       const std::string& set_example, std::string& device, int& threads, std::string& precision);

}  // namespace flat::cli
