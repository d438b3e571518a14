// flat_bench train: time one training step of a stage config, by part
// (include/flat/bench/step_benchmark.h), with peak memory.
//
//   flat_bench train --config configs/stage1.yaml --set data.datasets=[{root: /data/synth}] --random-lpips
#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include "bench_registry.h"
#include "flat/core/cli.h"
#include "flat/core/config.h"
#include "flat/bench/step_benchmark.h"

namespace flat::bench {

void add_train(CLI::App& app) {
  struct Options {
    std::string config;
    std::vector<std::string> overrides;
    int64_t warmup = 3, steps = 10;
    bool random_lpips = false;
    bool profile = false;
  };
  auto o = std::make_shared<Options>();
  auto* sub = app.add_subcommand("train", "time one training step of a stage config, by part, with peak memory");
  sub->add_option("--config", o->config, "stage config (YAML)")->required()->check(CLI::ExistingFile);
  cli::add_set(*sub, o->overrides, "data.batch_size=2");
  sub->add_option("--warmup", o->warmup, "untimed steps first")->capture_default_str();
  sub->add_option("--steps", o->steps, "timed steps")->capture_default_str();
  sub->add_flag("--random-lpips", o->random_lpips,
                "use random LPIPS weights of the right shapes (timing only; the cost does not depend on the values)");
  sub->add_flag("--profile", o->profile,
                "after timing, profile one step and one LPIPS run (CUDA): GPU time by phase, kernel class and kernel");
  sub->callback([o] {
    auto overrides = o->overrides;
    if (o->random_lpips) {
      const std::string path = "/tmp/flat_bench_random_lpips.safetensors";
      bench::write_random_lpips_weights(path, 0);
      overrides.push_back("loss.lpips_weights=" + path);
    }
    overrides.push_back("init.from=scratch");
    overrides.push_back("init.path=''");
    auto cfg = config::load_layered<train::TrainConfig>("", "<defaults>", {o->config}, overrides);
    spdlog::info("flat_bench train: {} at {}x{}, {} input frames, {} target views, batch {}, {}", o->config,
                 cfg.data.height, cfg.data.width, cfg.data.input_frames, cfg.data.target_views, cfg.data.batch_size,
                 cfg.precision);
    auto r = bench::benchmark_training(cfg, o->warmup, o->steps, o->profile);
    std::printf("flat_bench train: %s, %.2f M parameters, %lld triangles rendered per step, %lld timed steps\n%s"
                "peak memory: %.2f GiB\n",
                o->config.c_str(), r.parameters_m, static_cast<long long>(r.triangles),
                static_cast<long long>(r.steps), r.table().c_str(), r.peak_gib);
  });
}

}  // namespace flat::bench
