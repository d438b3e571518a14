// Everything a training run reads from its YAML file (configs/stage*.yaml,
// configs/tiny/*.yaml); `flat_train --help-config` prints every key with its
// default and meaning (docs/config.md is generated from it). A --config file
// layers over these defaults, and --set a.b=v over the file. The paper's
// values (Model Training, Losses, appendix Training Details) are spelled out in
// configs/stage1..4.yaml; the defaults below are those of stage 1.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "flat/core/config.h"
#include "flat/data/loader.h"
#include "flat/loss/objective.h"
#include "flat/pipeline/scene_pipeline.h"

namespace flat::train {

// Where the weights of a stage come from.
struct InitConfig {
  // "scratch":    every weight from its initialiser (seeded);
  // "wan_vae":    conv2 and the decoder trunk from a Wan 2.1 VAE safetensors file
  //               (either key naming); the camera adapter starts at zero and the
  //               heads from their initialiser (paper: Feedforward Scene Decoder);
  // "checkpoint": the model weights of an earlier stage: a run folder (its
  //               latest checkpoint), a checkpoint folder, or a model
  //               .safetensors file. The optimiser and step start afresh.
  std::string from = "scratch";
  std::string path;

  template <class V>
  void visit(V& v) {
    v.field("from", from, config::one_of({"scratch", "wan_vae", "checkpoint"}), "scratch | wan_vae | checkpoint");
    v.field("path", path, "Wan VAE file, or earlier run / checkpoint folder / model file");
  }
  void check() const;
};

// The VAE stage (task: vae): the whole Wan 2.1 VAE (pipeline.model.vae's
// architecture) trained as a video autoencoder on the scenes' frames, so that
// its latents carry the scene and its decoder already maps them back to
// pixels (the premise of the paper's Feedforward Scene Decoder). The loss is
// l1 |x^ - x| + l2 (x^ - x)^2 + lpips LPIPS(x^, x) + kl KL(q(z|x) || N(0,1)),
// means over pixels and latent elements, on frames in [-1,1].
struct VaeStageConfig {
  double l1 = 1.0;
  double l2 = 0.0;
  double lpips = 0.0;  // needs loss.lpips_weights
  double kl = 1e-6;
  // Training windows the per-channel latent statistics are measured on at the
  // end (folded into the written VAE file, wan_vae.h).
  int64_t stats_samples = 64;
  template <class V>
  void visit(V& v) {
    v.field("l1", l1, config::non_negative(), "weight of the mean absolute reconstruction error");
    v.field("l2", l2, config::non_negative(), "weight of the mean squared reconstruction error");
    v.field("lpips", lpips, config::non_negative(), "weight of LPIPS on the reconstructed frames");
    v.field("kl", kl, config::non_negative(), "weight of the KL term (mean over latent elements)");
    v.field("stats_samples", stats_samples, config::positive(),
            "training windows the latent mean/std are measured on at the end");
  }
};

struct OptimConfig {
  std::string name = "adamw";  // "adamw" (fp32 state) | "adamw8bit" (block-wise 8-bit moments; paper, stage 4)
  double lr = 1e-4;            // paper
  double beta1 = 0.9;
  double beta2 = 0.999;
  double eps = 1e-8;
  double weight_decay = 0.01;
  int64_t warmup_steps = 0;         // linear warm-up from 0
  std::string schedule = "cosine";  // after warm-up: constant | cosine | linear (to min_lr_ratio * lr)
  double min_lr_ratio = 0.1;
  double grad_clip = 1.0;  // global L2 norm; 0 = off
  bool fused = true;       // CUDA: ATen's fused AdamW kernel for the fp32-state parameters
  bool fused_8bit = true;  // CUDA, adamw8bit: our fused kernel for the 8-bit-state parameters

  template <class V>
  void visit(V& v) {
    v.field("name", name, config::one_of({"adamw", "adamw8bit"}), "adamw (fp32 state) | adamw8bit (8-bit moments)");
    v.field("lr", lr, config::positive(), "peak learning rate");
    v.field("beta1", beta1, config::range(0.0, 0.999999), "Adam beta1");
    v.field("beta2", beta2, config::range(0.0, 0.999999), "Adam beta2");
    v.field("eps", eps, config::positive(), "Adam epsilon");
    v.field("weight_decay", weight_decay, config::non_negative(), "decoupled weight decay");
    v.field("warmup_steps", warmup_steps, config::non_negative(), "linear warm-up steps");
    v.field("schedule", schedule, config::one_of({"constant", "cosine", "linear"}), "schedule after warm-up");
    v.field("min_lr_ratio", min_lr_ratio, config::range(0.0, 1.0), "final lr / peak lr (cosine, linear)");
    v.field("grad_clip", grad_clip, config::non_negative(), "clip the global gradient norm to this (0 = off)");
    v.field("fused", fused, "ATen's fused multi-tensor AdamW for the fp32-state parameters (CUDA and CPU); false: op by op");
    v.field("fused_8bit", fused_8bit,
            "CUDA, adamw8bit: our fused kernel for the 8-bit-state parameters (one per tensor); false: ATen ops");
  }
};

struct CheckpointConfig {
  int64_t every = 1000;  // steps; also written on SIGINT/SIGTERM and at the end
  int64_t keep = 3;      // newest checkpoints kept
  template <class V>
  void visit(V& v) {
    v.field("every", every, config::positive(), "write a checkpoint every N steps");
    v.field("keep", keep, config::positive(), "keep the newest K checkpoints");
  }
};

struct ValidationConfig {
  std::vector<data::DatasetSource> datasets;  // held-out scenes (empty: no validation)
  int64_t every = 1000;                       // steps (and before the first and after the last)
  int64_t scenes = 4;                         // held-out scenes scored (the first in name order)
  int64_t max_views = 16;                     // views per scene, evenly spaced (0 = every frame)
  double fall_warning_db = 0.5;               // warn when a validation falls this far below the best (0 = never)
  int64_t grid_views = 4;                     // samples in the PNG grid, one view each (0 = none)
  template <class V>
  void visit(V& v) {
    v.list("datasets", datasets);
    v.field("every", every, config::positive(), "validate every N steps");
    v.field("scenes", scenes, config::positive(),
            "held-out scenes scored at each validation (the first in name order; task: vae: held-out windows)");
    v.field("max_views", max_views, config::non_negative(),
            "views scored per held-out scene, evenly spaced over its frames (0 = all; flat_eval --max-views N "
            "scores the same views)");
    v.field("fall_warning_db", fall_warning_db, config::non_negative(),
            "after the warm-up, warn (log and logs/val_falls.jsonl) when the held-out PSNR falls more than this "
            "below the best before it (0 = never); the best model is kept in best/ either way");
    v.field("grid_views", grid_views, config::non_negative(),
            "held-out samples in the validation image grid, one view each (0 = none)");
  }
};

struct LogConfig {
  std::string level = "info";
  double progress_seconds = 10;  // a log line this often when stdout is not a terminal
  bool tensorboard = true;       // <run>/tensorboard/events.out.tfevents.*
  template <class V>
  void visit(V& v) {
    v.field("level", level, config::one_of({"trace", "debug", "info", "warn", "error"}), "log level");
    v.field("progress_seconds", progress_seconds, config::positive(), "progress log interval off a terminal");
    v.field("tensorboard", tensorboard, "also write the scalars as TensorBoard event files");
  }
};

// Data-parallel training (flat_train --nproc N, or RANK/WORLD_SIZE/... from
// torchrun or SLURM; docs/training.md, Multi-GPU). Unused in one process.
struct DistributedConfig {
  std::string backend = "auto";  // auto: nccl on CUDA, gloo on the CPU (store where gloo is missing)
  double timeout_seconds = 60;   // a collective, or a peer's heartbeat, waited for longer than this fails
  double bucket_mb = 25;         // gradient all-reduce bucket size (PyTorch DDP's default)
  // Start a bucket's all-reduce from autograd hooks while backward runs. With
  // the gradients in the buckets themselves (no copy, no host sync per bucket)
  // it hides the all-reduce: 99.5% scaling efficiency at stage 1 on 2 H200s
  // against 95.1-95.4% after backward (docs/benchmarks.md).
  bool overlap = true;
  // The gradients' dtype on the wire: fp32 (exact means) or bf16 (half the
  // bytes; ~3 significant digits of the mean, as DDP's bf16 compression hook).
  std::string grad_dtype = "fp32";
  template <class V>
  void visit(V& v) {
    v.field("backend", backend, config::one_of({"auto", "nccl", "gloo", "store"}),
            "auto (nccl on CUDA, gloo on the CPU) | nccl | gloo | store");
    v.field("timeout_seconds", timeout_seconds, config::positive(),
            "a collective or a silent peer fails after this long, naming the rank");
    v.field("bucket_mb", bucket_mb, config::positive(), "gradient all-reduce bucket size (MB)");
    v.field("overlap", overlap, "all-reduce gradient buckets during backward (false: after it)");
    v.field("grad_dtype", grad_dtype, config::one_of({"fp32", "bf16"}),
            "gradients' dtype in the all-reduce: fp32 (exact) | bf16 (half the bytes, ~3 significant digits)");
  }
};

struct NanGuardConfig {
  int64_t max_consecutive = 20;  // this many non-finite steps in a row stop the run
  template <class V>
  void visit(V& v) {
    v.field("max_consecutive", max_consecutive, config::positive(),
            "stop after this many consecutive steps with a non-finite loss or gradient");
  }
};

// For tests of the failure paths; never set in a real run.
struct DebugConfig {
  std::vector<int64_t> nan_steps;  // steps whose input latents are replaced by NaN
  template <class V>
  void visit(V& v) { v.field("nan_steps", nan_steps, "(testing) steps fed NaN latents"); }
};

struct TrainConfig {
  std::string run_dir = "runs/train";
  std::string stage = "stage1";  // a name for logs and checkpoints
  std::string task = "scene";    // scene: the scene decoder on latents; vae: the Wan VAE on frames
  int64_t steps = 20000;         // paper, stage 1
  // Training renders prune at pipeline.prune_opacity * min(1, step / this):
  // a stage that starts pruning (stage 4) raises the threshold gradually
  // instead of removing most of the previous stage's soft triangles at step 0
  // (pruned triangles get no gradient). Validation prunes at the full value.
  int64_t prune_warmup_steps = 0;
  // A fresh start that prunes: the training batches on which opacity shifts
  // are tried before step 0 (train/opacity_calibration.h); 0: none.
  int64_t opacity_shift_calibration = 0;
  std::string device = "cuda";
  std::string precision = "bf16";  // bf16: autocast on CUDA, fp32 master weights; fp32
  int64_t seed = 0;
  int64_t threads = 0;  // CPU intra-op threads (0 = libtorch's default less data.workers)
  bool cudnn_benchmark = true;  // cuDNN times its conv algorithms once per new shape (a stage's shapes are fixed)
  InitConfig init;
  OptimConfig optim;
  CheckpointConfig checkpoint;
  ValidationConfig validation;
  LogConfig log;
  NanGuardConfig nan_guard;
  DistributedConfig distributed;
  data::LoaderConfig data;
  pipeline::PipelineConfig pipeline;
  loss::LossConfig loss;
  VaeStageConfig vae;
  DebugConfig debug;

  template <class V>
  void visit(V& v) {
    v.field("run_dir", run_dir, "run folder (config, logs, metrics, checkpoints, renders)");
    v.field("stage", stage, "stage name (logs, checkpoints)");
    v.field("task", task, config::one_of({"scene", "vae"}),
            "scene: train the scene decoder on latents | vae: train the Wan VAE on the frames (its own stage)");
    v.field("steps", steps, config::positive(), "optimisation steps of this stage");
    v.field("prune_warmup_steps", prune_warmup_steps, config::non_negative(),
            "steps over which the training renders' pruning threshold rises linearly from 0 to "
            "pipeline.prune_opacity (0: the full threshold from step 0; validation always uses the full one)");
    v.field("opacity_shift_calibration", opacity_shift_calibration, config::non_negative(),
            "a fresh start with pipeline.prune_opacity > 0: on this many training batches, try "
            "pipeline.triangles.opacity_shift lowered by 0 to 6 in steps of 0.5 (every opacity raised together) and "
            "train with the one whose pruned renders fit best; written into the run's config and model (0: off)");
    v.field("device", device, config::one_of({"cpu", "cuda"}), "cpu | cuda");
    v.field("precision", precision, config::one_of({"bf16", "fp32"}), "bf16 autocast (CUDA) or fp32");
    v.field("seed", seed, "seed of the weights' initialisation and every random draw");
    v.field("threads", threads, config::non_negative(),
            "CPU intra-op threads (0: the cores, or OMP_NUM_THREADS, less data.workers; at least 1)");
    v.field("cudnn_benchmark", cudnn_benchmark,
            "CUDA: cuDNN times its convolution algorithms once for each new shape and keeps the fastest "
            "(a stage's shapes are fixed; false: cuDNN's heuristics)");
    v.section("init", init);
    v.section("optim", optim);
    v.section("checkpoint", checkpoint);
    v.section("validation", validation);
    v.section("log", log);
    v.section("nan_guard", nan_guard);
    v.section("distributed", distributed);
    v.section("data", data);
    v.section("pipeline", pipeline);
    v.section("loss", loss);
    v.section("vae", vae);
    v.section("debug", debug);
  }
  void check() const;
};

// Every key of TrainConfig with its default and help, as a Markdown table
// (flat_train --help-config, docs/config.md).
std::string describe_config();

}  // namespace flat::train
