// Training checkpoints: one folder per checkpoint,
//
//   <run>/checkpoints/step_00001000/
//     model.safetensors      the scene decoder's weights (Wan key names), with
//                            the model's architecture in the metadata
//     optimizer.safetensors  AdamW state (adamw.h)
//     rng.safetensors        CPU and CUDA generator states
//     trainer.json           step, stage, NaN-guard counters, effective config
//
// written into a hidden ".incomplete-..." folder first and renamed when every
// file is on disk, so a crash (even SIGKILL) in the middle of a write leaves
// the previous checkpoints as they were and no folder that looks complete.
// The newest `keep` are kept, and never at the cost of the newest good one
// (written while no step was being skipped): a run stuck in non-finite steps
// cannot prune away the last checkpoint worth resuming. A checkpoint of
// non-finite weights is never written. A truncated or altered file fails to
// load with an error naming it; --resume then falls back to the newest
// intact checkpoint (load_newest_intact_checkpoint).
#pragma once
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <torch/nn/module.h>

#include "flat/core/tensor_io.h"
#include "flat/pipeline/trained_model.h"
#include "flat/optim/adamw.h"

namespace flat::train {

struct TrainerState {
  int64_t step = 0;  // optimisation steps done (the next step has this index)
  std::string stage;
  int64_t skipped_steps = 0;      // non-finite steps skipped so far
  int64_t consecutive_skips = 0;  // ... in a row, at the time of the checkpoint
  std::string config_yaml;        // the run's effective config
};

// The model's architecture signature and pipeline config, written into every
// model file (pipeline/trained_model.h).
using pipeline::ModelSignature;

// Writes step_<step> under checkpoints_dir and removes all but the newest
// `keep` (keeping the newest good one, see above). Returns the folder written.
// Throws flat::Error naming the folder, and writes nothing, when the model's
// weights hold NaN or Inf.
std::string save_checkpoint(const std::string& checkpoints_dir, const TrainerState& state,
                            const torch::nn::Module& model, const ModelSignature& signature, const optim::AdamW& optimiser,
                            int64_t keep);

// The newest complete checkpoint folder under checkpoints_dir, "" if none.
// Leftover ".incomplete-*" folders of a crashed write are removed (logged).
std::string latest_checkpoint(const std::string& checkpoints_dir);
// Where save_checkpoint puts step `step`: <checkpoints_dir>/step_<8 digits>.
std::string checkpoint_folder(const std::string& checkpoints_dir, int64_t step);
// Complete checkpoint folders, oldest first.
std::vector<std::string> list_checkpoints(const std::string& checkpoints_dir);

struct LoadedCheckpoint {
  std::string dir;
  TrainerState state;
  TensorMap model, optimiser, rng;
  ModelSignature signature;
};
// Reads and validates every file of a checkpoint folder (throws naming the file).
LoadedCheckpoint read_checkpoint(const std::string& dir);

// What --resume starts from: the newest checkpoint folder under
// checkpoints_dir that reads back whole (trainer.json present and valid,
// every file intact) with finite model and optimiser tensors. Newer ones
// that fail are logged with the reason, listed in `skipped` ("<folder>:
// <reason>") and moved aside to "<folder>.broken-<pid>" for inspection, out
// of the listing and the pruning. Returns nothing when the folder holds no
// checkpoint; throws flat::Error naming every folder and its fault when none
// of them is intact (then nothing is moved). Leftover ".incomplete-*"
// folders are removed first, as by latest_checkpoint.
std::optional<LoadedCheckpoint> load_newest_intact_checkpoint(const std::string& checkpoints_dir,
                                                               std::vector<std::string>* skipped = nullptr);

using pipeline::load_model_weights;
using pipeline::resolve_model_file;

// Generator states: "cpu", "cuda.<i>" for every visible CUDA device.
TensorMap capture_rng();
void restore_rng(const TensorMap& rng, const std::string& label);

// Test hook: with FLAT_TEST_KILL_IN_CHECKPOINT=<step> in the environment the
// process SIGKILLs itself halfway through writing that step's checkpoint.
inline constexpr const char* kKillInCheckpointEnv = "FLAT_TEST_KILL_IN_CHECKPOINT";

}  // namespace flat::train
