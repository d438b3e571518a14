// What one training process holds while it trains: the model of the stage's
// task (task: scene, the scene decoder with its pipeline and objective; task:
// vae, the Wan VAE and its reconstruction loss, vae_stage.h) with its initial
// weights (scratch, a Wan VAE file or an earlier stage), the optimiser and the
// learning-rate schedule, and the one optimisation step built from them. The
// trainer's loop and flat_bench train both drive this, so the timed step is
// the trained step.
#pragma once
#include <memory>

#include "flat/loss/objective.h"
#include "flat/pipeline/scene_pipeline.h"
#include "flat/optim/adamw.h"
#include "flat/train/checkpoint.h"
#include "flat/train/lr_schedule.h"
#include "flat/train/train_config.h"
#include "flat/train/train_step.h"
#include "flat/train/vae_stage.h"

namespace flat::train {

class DataParallel;

struct StepOutcome {
  StepResult result;       // with data parallelism: over all ranks (data_parallel.h)
  int stop_signal = 0;     // the stop request of step(), agreed by all ranks
  double lr = 0;
  double grad_norm = NAN;
  bool applied = false;  // false: non-finite loss or gradient, the update was skipped
  double optimiser_seconds = 0;  // grad norm, clipping and update (timed runs only)
};

class TrainingSession {
 public:
  // Builds the model on cfg.device (or on `device`: cuda:LOCAL_RANK for a
  // rank of a data-parallel run) and initialises it as cfg.init says.
  explicit TrainingSession(const TrainConfig& cfg);
  TrainingSession(const TrainConfig& cfg, const at::Device& device);

  // zero grads -> forward/backward -> global grad norm -> skip if not finite,
  // else clip and update with the schedule's lr at `step`. times: per-phase
  // timing with device synchronisation (flat_bench train). stop_signal: a
  // pending SIGINT/SIGTERM (0: none), returned as StepOutcome::stop_signal.
  // With data parallelism the gradients are averaged over the ranks before
  // the norm, and the ranks agree on the skip and the stop.
  StepOutcome step(const data::Batch& batch, int64_t step, StepTimes* times = nullptr, int stop_signal = 0);

  // The scene decoder's triangles.opacity_shift from now on, in its pipeline
  // and in the signature that checkpoints and the model file carry.
  void set_opacity_shift(double shift);

  // From now on step() averages gradients over `dp`'s ranks (dp outlives this
  // session's steps); call after the weights are final (init, resume, shared).
  void use_data_parallel(DataParallel* dp);

  // The module being trained (the scene decoder or the VAE): what checkpoints
  // hold and what the optimiser updates.
  torch::nn::Module& model();
  bool vae_task() const { return !vae.is_empty(); }

  // task: scene
  model::SceneDecoder decoder{nullptr};
  std::unique_ptr<pipeline::ScenePipeline> pipeline;
  std::unique_ptr<loss::Objective> objective;
  // task: vae
  model::WanVAE vae{nullptr};
  loss::Lpips vae_lpips{nullptr};  // loaded when vae.lpips > 0
  VaeStageConfig vae_loss;

  std::unique_ptr<optim::AdamW> optimiser;
  LrSchedule schedule;
  ModelSignature signature;
  at::Device device = at::kCPU;
  bool bf16 = false;

 private:
  double grad_clip_ = 0;
  int64_t background_seed_ = -1;  // loss.random_background: the run's seed (a step's colours follow from it); -1: off
  double prune_opacity_ = 0;        // pipeline.prune_opacity, reached after prune_warmup_steps_
  int64_t prune_warmup_steps_ = 0;
  DataParallel* dp_ = nullptr;
};

using pipeline::model_signature;

// The VAE stage's architecture signature (checkpoints of task: vae).
ModelSignature vae_signature(const model::WanVAEConfig& config);

}  // namespace flat::train
