// flat_train: trains the FLAT scene decoder, one stage per run folder
// (src/train/trainer.h says what a run folder holds).
//
//   flat_train --config configs/tiny/stage1.yaml            a new run
//   flat_train --config configs/stage2.yaml --set steps=500  keys overridden
//   flat_train --resume runs/tiny-stage1                    continue after a kill
//   flat_train --config configs/stage1.yaml --nproc 8       data-parallel, one process per GPU
//   flat_train --help-config                                every key, default, meaning
//
// Under torchrun or SLURM (RANK, WORLD_SIZE, ... set) each process is one
// rank; --nproc N starts N such processes itself (distributed/local_launcher.h).
//
// Exit codes: 0 finished, 1 runtime error (message names the file or key; a
// failed rank), 2 usage error, 128 + signal when stopped by SIGINT/SIGTERM/SIGHUP
// (checkpoint written).
#include <cstdlib>
#include <iostream>

#include <CLI/CLI.hpp>

#include "flat/core/cli.h"
#include "flat/core/config.h"
#include "flat/core/error.h"
#include "flat/core/log.h"
#include "flat/distributed/distributed_env.h"
#include "flat/distributed/local_launcher.h"
#include "flat/train/trainer.h"

int main(int argc, char** argv) {
  CLI::App app{"flat_train: train the FLAT scene decoder (one stage of the paper's schedule per run folder)"};
  app.get_formatter()->column_width(34);
  std::vector<std::string> config_files;
  std::string resume_dir, log_level, device, precision;
  std::vector<std::string> overrides;
  bool overwrite = false, print_config = false, help_config = false;
  int nproc = 1;
  app.add_option("--config", config_files,
                 "stage config (YAML), layered over the defaults (--help-config); repeat it to layer more files in "
                 "order, e.g. a stage config then an ablation (configs/ablations/)")
      ->check(CLI::ExistingFile)
      ->take_all();
  app.add_option("--resume", resume_dir, "continue the run in this folder from its newest checkpoint");
  flat::cli::add_set(app, overrides, "steps=500 --set optim.lr=2e-4 --set pipeline.prune_opacity=0.4");
  app.add_flag("--overwrite", overwrite,
               "start afresh in a run_dir that holds a run (replaced only once the new run has loaded everything; "
               "a folder that is not a run folder is refused)");
  app.add_option("--log-level", log_level, "trace|debug|info|warn|error (default: the config's log.level)")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error"}));
  app.add_option("--device", device, "auto | cpu | cuda: overrides the config's device (auto = cuda when present)")
      ->check(CLI::IsMember({"auto", "cpu", "cuda"}));
  app.add_option("--precision", precision, "compute dtype: fp32 | bf16: overrides the config's precision")
      ->check(CLI::IsMember({"fp32", "bf16"}));
  int threads = 0;
  auto* threads_option = app.add_option("--threads", threads, "CPU threads (0: every core): overrides the config's threads")
                             ->check(CLI::Range(0, 4096));
  app.add_option("--nproc", nproc, "data-parallel: start N worker processes on this host (one per GPU)")
      ->check(CLI::Range(1, 1024));
  app.add_flag("--print-config", print_config, "print the effective config and exit");
  app.add_flag("--help-config", help_config, "print every config key with its default and meaning");
  app.set_version_flag("--version", std::string("flat_train ") + flat::cli::kVersion);
  if (int rc = flat::cli::parse(app, argc, argv); rc >= 0) return rc;
  try {
    flat::setup_logging(log_level.empty() ? "info" : log_level);
    if (help_config) {
      std::cout << flat::train::describe_config();
      return 0;
    }
    if (!log_level.empty()) overrides.push_back("log.level=" + log_level);
    if (!device.empty()) overrides.push_back(std::string("device=") + (flat::cli::resolve_device(device).is_cuda() ? "cuda" : "cpu"));
    if (!precision.empty()) overrides.push_back("precision=" + precision);
    if (threads_option->count() > 0) overrides.push_back("threads=" + std::to_string(threads));
    if (resume_dir.empty() == config_files.empty()) {
      std::cerr << "flat_train: give exactly one of --config FILE (a new run, e.g. configs/tiny/stage1.yaml) or "
                   "--resume RUN_DIR\n";
      return 2;
    }
    if (!resume_dir.empty() && overwrite) {
      std::cerr << "flat_train: --resume and --overwrite contradict each other\n";
      return 2;
    }
    std::string yaml;
    flat::train::TrainConfig cfg;
    auto mode = flat::train::StartMode::fresh;
    if (!resume_dir.empty()) {
      cfg = flat::train::load_run_config(resume_dir, overrides, &yaml);
      mode = flat::train::StartMode::resume;
    } else {
      cfg = flat::config::load_layered<flat::train::TrainConfig>("", "<defaults>", config_files, overrides);
      yaml = flat::config::to_yaml(cfg);
      if (overwrite) mode = flat::train::StartMode::overwrite;
    }
    if (print_config) {
      std::cout << yaml;
      return 0;
    }
    if (nproc > 1) {
      if (std::getenv("RANK") || std::getenv("WORLD_SIZE")) {
        std::cerr << "flat_train: --nproc starts its own ranks; under torchrun or SLURM (RANK/WORLD_SIZE set) "
                     "leave it out\n";
        return 2;
      }
      flat::distributed::LaunchOptions launch;
      launch.nproc = nproc;
      launch.args = flat::distributed::drop_option(std::vector<std::string>(argv + 1, argv + argc), "--nproc");
      // Past a failure the others get the timeout to notice and report it themselves.
      launch.grace = std::chrono::milliseconds(int64_t(cfg.distributed.timeout_seconds * 1000) + 5000);
      return flat::distributed::launch_local_workers(launch);
    }
    return flat::train::run_training(cfg, yaml, mode, flat::distributed::read_distributed_env()).exit_code;
  } catch (...) {
    return flat::report_current_error();
  }
}
