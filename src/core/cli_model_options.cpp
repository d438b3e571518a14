#include "flat/core/cli_model_options.h"

#include "flat/core/cli.h"

namespace flat::cli {

void add_model_options(CLI::App& app, std::string& config, std::vector<std::string>& overrides,
                       const std::string& set_example, std::string& device, int& threads, std::string& precision) {
  app.add_option("--config", config, "pipeline keys (YAML) layered over the config the model carries");
  add_set(app, overrides, set_example);
  add_device(app, device);
  add_threads(app, threads);
  add_precision(app, precision)
      ->description("compute dtype: fp32 | bf16 (bf16 applies on CUDA; on the CPU the run is fp32 whatever this says)");
}

}  // namespace flat::cli
