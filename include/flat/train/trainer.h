// The staged trainer behind flat_train (paper, Model Training; appendix,
// Training Details): one stage per run folder, driven by a TrainConfig.
//
//   run folder <run_dir>/
//     config.yaml          the effective config (what --resume reads back)
//     logs/train.log       everything printed, appended across sessions
//     metrics/train.jsonl  one object per step: loss terms, lr, grad norm, it/s
//     metrics/val.jsonl    one object per validation
//     tensorboard/         the same scalars as TensorBoard event files
//     checkpoints/step_*/  the newest checkpoint.keep checkpoints (checkpoint.h)
//     renders/val_step_*.png  validation grids
//     model.safetensors    the final weights (Wan key names), for flat_infer
//     vae.safetensors      instead, for task: vae: the trained Wan VAE (vae_stage.h)
//
// Checkpoints are written every checkpoint.every steps, at the end, and when
// SIGINT, SIGTERM or SIGHUP arrives (the run then stops with exit code 128 + signal;
// with several ranks, when any rank got one: they agree every step).
// A resumed run continues exactly: on the CPU its losses equal an
// uninterrupted run's bit for bit. It starts from the newest intact
// checkpoint (broken newer ones are named and set aside, checkpoint.h), and
// the validation due at that step is run again, so val.jsonl keeps every row. A step whose loss or gradient is not finite
// is skipped and counted; nan_guard.max_consecutive in a row stop the run with
// its last good checkpoint intact.
#pragma once
#include <string>
#include <vector>

#include "flat/distributed/distributed_env.h"
#include "flat/train/train_config.h"

namespace flat::train {

enum class StartMode {
  fresh,      // a new run folder; refuse one that already holds a run
  resume,     // continue the run in run_dir from its newest checkpoint
  overwrite,  // replace run_dir (only a run folder), once the new run has loaded everything
};

struct TrainSummary {
  int exit_code = 0;  // 0 finished; 128 + signal when stopped by SIGINT/SIGTERM/SIGHUP
  int64_t first_step = 0, steps_done = 0;
  int64_t skipped_steps = 0;
  double first_val_psnr = NAN, last_val_psnr = NAN, mean_colour_psnr = NAN;
  double dataset_mean_psnr = NAN, swap_psnr = NAN;  // the last validation's baselines
  std::string run_dir, last_checkpoint, model_file;
};

// Runs (or resumes) the stage. `config_yaml` is the effective config saved in
// the run folder. Throws flat::Error on bad input, naming the file or key.
// `env` (distributed::read_distributed_env()): with more than one rank every
// rank calls this with the same config and trains its share of each batch;
// rank 0 alone writes in the run folder (data_parallel.h, docs/training.md).
TrainSummary run_training(const TrainConfig& config, const std::string& config_yaml, StartMode mode,
                          const distributed::DistributedEnv& env = {});

// Test hook: with FLAT_TEST_SIGNAL_IN_VALIDATION=<step> in the environment the
// process SIGKILLs itself inside the validation of that step, before its row
// is written; "<step>:<signal>" raises that signal instead.
inline constexpr const char* kSignalInValidationEnv = "FLAT_TEST_SIGNAL_IN_VALIDATION";
// Test hook: with FLAT_TEST_SIGNAL_IN_STARTUP=<signal> the process raises that
// signal during start-up, once the model is built and before the checkpoint
// is looked for (a SIGTERM there is far too short a window to hit from outside).
inline constexpr const char* kSignalInStartupEnv = "FLAT_TEST_SIGNAL_IN_STARTUP";

// The run folder's saved config (for --resume), with overrides applied.
TrainConfig load_run_config(const std::string& run_dir, const std::vector<std::string>& overrides,
                            std::string* effective_yaml);

}  // namespace flat::train
