#include "flat/train/trainer.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <optional>

#include <c10/core/impl/DeviceGuardImplInterface.h>
#include <spdlog/sinks/stdout_color_sinks.h>

#include <torch/torch.h>

#include "flat/core/device_memory.h"
#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/log.h"
#include "flat/core/progress.h"
#include "flat/core/run_dir.h"
#include "flat/model/weights.h"
#include "flat/optim/adamw.h"
#include "flat/train/best_validation.h"
#include "flat/train/checkpoint.h"
#include "flat/train/data_parallel.h"
#include "flat/train/data_report.h"
#include "flat/train/lr_schedule.h"
#include "flat/train/metrics_log.h"
#include "flat/train/opacity_calibration.h"
#include "flat/train/train_step.h"
#include "flat/train/training_session.h"
#include "flat/train/validation.h"
#include "train/run_folder.h"
#include "train/stop_signals.h"

namespace flat::train {
namespace fs = std::filesystem;

namespace {

// ---- helpers -------------------------------------------------------------------

// Ranks other than 0 write nothing in the run folder: their warnings and
// errors go to stderr, each line naming the rank.
void setup_rank_logging(const std::string& level, const distributed::DistributedEnv& env) {
  setup_logging(level);  // checks the level's name
  auto logger = std::make_shared<spdlog::logger>("flat", std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
  logger->set_level(std::max(spdlog::level::from_str(level), spdlog::level::warn));
  logger->set_pattern("[%Y-%m-%d %H:%M:%S.%e] [rank " + std::to_string(env.rank) + "/" +
                      std::to_string(env.world_size) + "] [%^%l%$] %v");
  logger->flush_on(spdlog::level::warn);
  spdlog::set_default_logger(logger);
}

// checkpoints/step_00000040 -> 40.
int64_t ckpt_step(const std::string& dir) {
  const std::string name = fs::path(dir).filename().string();
  return std::stoll(name.substr(name.find('_') + 1));
}

// ---- the run -------------------------------------------------------------------
// One call of run_training, section by section: run_training calls these in
// the order they are declared. What one section leaves for the next is a
// member; members are declared in the order they come to life, so they go
// (on return or while an exception unwinds) in the reverse order, last
// the stop-signal handlers.
class Run {
 public:
  Run(const TrainConfig& cfg, const std::string& config_yaml, StartMode mode, const distributed::DistributedEnv& env)
      : cfg_(cfg), config_yaml_(config_yaml), mode_(mode), env_(env), rank0_(env.rank == 0) {}

  // Checks of the run folder (rank 0), logging, stop signals, seeds; this
  // rank's device and, with several ranks, the process group.
  void start_ranks();
  // The model of the stage's task, its objective and optimiser.
  void start_session();
  // Continues from the newest intact checkpoint (--resume) or starts at step
  // 0; then every rank holds rank 0's weights.
  void resume_or_start_fresh();
  // The training loader (this rank's share of each batch) and the validation
  // loader, and what validation compares with.
  void open_loaders();
  // A fresh start that prunes, with opacity_shift_calibration: the opacity
  // shift its pruned renders fit best (train/opacity_calibration.h), from now
  // on in the pipeline, the signature and the config the run folder keeps.
  void calibrate_opacity_shift();
  // Everything has loaded: only now is the run folder replaced (--overwrite)
  // or created, and written in.
  void open_run_folder();
  enum class LoopEnd { completed, stopped_by_signal };
  // Validation at the first step, then the steps to cfg.steps with their
  // metrics, checkpoints, validations, NaN guard and stop requests.
  LoopEnd train();
  // The final model file and the closing lines (after a completed loop), then
  // the clean end on every rank.
  TrainSummary finish(LoopEnd end);

 private:
  StepOutcome take_step(int64_t step);
  void count_step(int64_t step, const StepOutcome& out);
  void write_step_metrics(int64_t step, const StepOutcome& out, double seconds);
  LoopEnd stop_by_signal(int stop);
  void check_something_learned();
  void note_random_latents();
  void pick_held_out_scenes();
  void log_run_start();
  void run_validation(int64_t step);
  void write_checkpoint();
  void write_model_file(const std::string& path);
  TrainSummary end_ranks();

  torch::nn::Module& net() { return session_->model(); }  // the trained module
  optim::AdamW& optimiser() { return *session_->optimiser; }
  const ModelSignature& signature() const { return session_->signature; }
  bool bf16() const { return session_->bf16; }

  TrainConfig cfg_;          // the caller's, but for a calibrated opacity shift
  std::string config_yaml_;  // what config.yaml and the checkpoints keep (to_yaml of cfg_ once calibrated)
  const StartMode mode_;
  const distributed::DistributedEnv& env_;
  const bool rank0_;  // rank 0: the only rank that writes in the run folder

  std::optional<StopSignals> stop_signals_;  // installed by start_ranks, restored last
  TrainSummary summary_;
  RunDir run_dir_;  // paths only: created once everything has loaded (open_run_folder)
  at::Device device_{at::kCPU};  // this rank's device: cfg.device, cuda:LOCAL_RANK with several ranks
  std::unique_ptr<DataParallel> dp_;  // with more than one rank
  std::optional<TrainingSession> session_;
  TrainerState state_;  // what checkpoints hold besides the weights: step, skips, stage, config
  data::LoaderConfig train_data_;  // this rank's share of each batch
  std::optional<data::Loader> train_loader_;
  std::unique_ptr<data::Loader> val_loader_;  // none without validation.datasets
  std::string random_latents_;  // which scenes hold random-encoder latents; empty: none
  std::string data_report_;     // data_report.json: what each loader used and left out
  std::vector<std::string> data_summary_;  // the same, for the log
  HeldOut val_scenes_;  // scene task: the held-out scenes, scored as flat_eval scores them
  eval::EvalSettings val_settings_;
  std::unique_ptr<MetricsLog> metrics_;  // rank 0
  std::optional<BestValidation> best_;   // rank 0: the best held-out validation, kept in best/
  std::optional<Progress> progress_;     // rank 0, while steps remain
  int64_t applied_steps_ = 0;            // steps of this session whose update was applied
};

void Run::start_ranks() {
  // Data parallelism: rank 0 alone touches the run folder (logs, metrics,
  // TensorBoard, checkpoints, validation grids, the final model); the other
  // ranks log warnings and errors to stderr with their rank.
  if (rank0_) {
    check_run_folder(cfg_.run_dir, mode_);
    setup_logging(cfg_.log.level);
  } else {
    setup_rank_logging(cfg_.log.level, env_);
  }
  // From here to the end a stop request is honoured: one that comes during
  // start-up or a validation is acted on after the next step (a checkpoint,
  // then exit 128 + signal).
  stop_signals_.emplace();
  summary_.run_dir = cfg_.run_dir;
  run_dir_ = RunDir{cfg_.run_dir};

  // threads: 0 -> libtorch's default (the cores, or OMP_NUM_THREADS as the
  // launcher sets it per rank) less the loader's prefetch threads, which
  // otherwise fight the intra-op threads for the same cores (2 cores: the tiny
  // VAE stage ran 10.0 it/s with 1 intra-op thread, 5.5 with 2).
  at::set_num_threads(int(cfg_.threads > 0 ? cfg_.threads
                                            : std::max<int64_t>(1, int64_t(at::get_num_threads()) - cfg_.data.workers)));
  spdlog::info("CPU threads: {} intra-op, {} loader", at::get_num_threads(), cfg_.data.workers);
  torch::manual_seed(uint64_t(cfg_.seed));

  // ---- ranks ---------------------------------------------------------------------
  // One GPU per rank: cuda:LOCAL_RANK, the current device before NCCL starts
  // (kernels launched without a device of their own go there too).
  device_ = at::Device(cfg_.device == "cuda" ? at::kCUDA : at::kCPU);
  if (device_.is_cuda() && env_.distributed()) {
    device_ = at::Device(at::kCUDA, static_cast<c10::DeviceIndex>(env_.local_rank));
    const int64_t gpus = torch::cuda::is_available() ? int64_t(torch::cuda::device_count()) : 0;
    FLAT_CHECK(env_.local_rank < gpus, "distributed: rank " + std::to_string(env_.rank) + " has LOCAL_RANK " +
                                           std::to_string(env_.local_rank) + " but this host shows " +
                                           std::to_string(gpus) + " CUDA device(s): start at most that many ranks "
                                           "per host (--nproc, --nproc-per-node) or check CUDA_VISIBLE_DEVICES");
    c10::impl::getDeviceGuardImpl(at::kCUDA)->setDevice(device_);
  }
  if (env_.distributed()) {
    dp_ = std::make_unique<DataParallel>(cfg_.distributed, env_, device_);
    spdlog::info("distributed: rank {} of {} on {}, backend {}, timeout {} s", env_.rank, env_.world_size,
                 device_.str(), dp_->backend(), cfg_.distributed.timeout_seconds);
  }
}

// ---- model, objective, optimiser ------------------------------------------------
void Run::start_session() { session_.emplace(cfg_, device_); }

// ---- resume ------------------------------------------------------------------
void Run::resume_or_start_fresh() {
  state_.stage = cfg_.stage;
  state_.config_yaml = config_yaml_;
  if (mode_ == StartMode::resume) {
    // Rank 0 picks the newest intact checkpoint (clearing a half-written one,
    // naming and setting aside broken ones); every rank loads it.
    std::optional<LoadedCheckpoint> loaded;
    if (rank0_) loaded = load_newest_intact_checkpoint(run_dir_.checkpoints());
    std::string latest = loaded ? loaded->dir : std::string();
    if (dp_) {
      const int64_t step = dp_->broadcast(latest.empty() ? -1 : ckpt_step(latest));
      latest = step < 0 ? std::string() : checkpoint_folder(run_dir_.checkpoints(), step);
    }
    if (latest.empty()) {
      spdlog::warn("resume: '{}' has no checkpoint yet; starting the stage from step 0", run_dir_.root);
    } else {
      auto ckpt = loaded ? std::move(*loaded) : read_checkpoint(latest);
      load_model_weights(net(), ckpt.model, ckpt.signature, signature(), latest + "/model.safetensors");
      optimiser().load_state(ckpt.optimiser, latest + "/optimizer.safetensors");
      restore_rng(ckpt.rng, latest + "/rng.safetensors");
      state_.step = ckpt.state.step;
      state_.skipped_steps = ckpt.state.skipped_steps;
      state_.consecutive_skips = ckpt.state.consecutive_skips;
      summary_.last_checkpoint = latest;
      spdlog::info("resume: {} at step {} of {}", latest, state_.step, cfg_.steps);
    }
  }
  summary_.first_step = state_.step;
  if (dp_) {
    // Every rank starts from rank 0's weights (the same seed and checkpoint
    // give them already; this makes sure), then averages its gradients.
    dp_->share_weights(net());
    session_->use_data_parallel(dp_.get());
  }
}

// ---- data --------------------------------------------------------------------
void Run::open_loaders() {
  // data.batch_size is per rank (as torchrun/DDP users expect, and as the
  // paper's 8 GPUs each hold one sample): rank r of W loads B samples,
  // (b*W + r)*B ..., so the W shares of a step are the batch one process with
  // B*W would load (loader.h) and the effective batch is B*W.
  train_data_ = cfg_.data;
  train_data_.camera_rays = cfg_.pipeline.model.camera_rays;  // the camera latents the model reads
  train_loader_.emplace(train_data_, state_.step, env_.rank, env_.world_size);
  if (cfg_.task == "scene") check_geometry_targets(cfg_.loss, *train_loader_);
  if (!cfg_.validation.datasets.empty()) {
    data::LoaderConfig v = cfg_.data;
    v.datasets = cfg_.validation.datasets;
    v.camera_rays = cfg_.pipeline.model.camera_rays;
    v.batch_size = 1;
    v.workers = 0;
    v.seed = 1000003;  // fixed: the same held-out views at every validation
    v.skip_bad_scenes = false;
    val_loader_ = std::make_unique<data::Loader>(v);
  } else {
    spdlog::warn("validation: no held-out datasets (validation.datasets); no validation metrics");
  }
  note_random_latents();
  if (val_loader_ && !session_->vae_task()) pick_held_out_scenes();
  data_report_ = data_report_json(*train_loader_, val_loader_.get(), env_.world_size, cfg_.data.batch_size);
  data_summary_ = data_summary(*train_loader_, val_loader_.get(), env_.world_size, cfg_.data.batch_size);
}

// Provenance: latents of a random-weight encoder carry almost nothing of the
// scene; every figure made from them says so.
void Run::note_random_latents() {
  if (session_->vae_task()) return;
  for (const auto* l : {&*train_loader_, val_loader_.get()}) {
    if (!l) continue;
    const auto enc = l->latent_encoders();
    if (enc.count("random"))
      random_latents_ += (random_latents_.empty() ? "" : "; ") + std::to_string(enc.at("random")) + " of " +
                         std::to_string(l->scene_count()) + (l == &*train_loader_ ? " training" : " held-out") +
                         " scenes";
  }
}

// The scene task's held-out scenes, scored as flat_eval scores them; the
// "same output for every scene" baseline is the training set's mean image.
void Run::pick_held_out_scenes() {
  val_settings_ = validation_settings(cfg_.validation.max_views, bf16());
  val_scenes_ = held_out_scenes(cfg_.validation.datasets, cfg_.validation.scenes, cfg_.data.height, cfg_.data.width,
                                cfg_.data.input_frames);
  val_scenes_.measure_frames(val_settings_);
  std::string names;
  for (const auto& s : val_scenes_.scenes) names += (names.empty() ? "" : ", ") + s.name;
  const std::string latent_set = data::latent_set_key(cfg_.data.height, cfg_.data.width, cfg_.data.input_frames);
  spdlog::info("validation: {} held-out scenes ({}), window 0 of latent set {}, {} views each, scored as flat_eval "
               "scores them (flat_eval --max-views {} --latent-set {})",
               val_scenes_.scenes.size(), names, latent_set,
               cfg_.validation.max_views ? "at most " + std::to_string(cfg_.validation.max_views) : "all",
               cfg_.validation.max_views, latent_set);
}

void Run::calibrate_opacity_shift() {
  if (session_->vae_task() || cfg_.opacity_shift_calibration == 0 || cfg_.pipeline.prune_opacity <= 0 ||
      state_.step > 0)
    return;
  const double prune = cfg_.pipeline.prune_opacity;
  const auto t0 = std::chrono::steady_clock::now();
  const auto c = train::calibrate_opacity_shift(*session_->pipeline, *session_->objective, *train_loader_,
                                                cfg_.opacity_shift_calibration, prune, bf16(),
                                                cfg_.loss.random_background ? int64_t(cfg_.seed) : -1, dp_.get());
  spdlog::info("opacity calibration: {} training batch(es), rendered pruned at {} as the steps will be, {:.1f} s:{}",
               cfg_.opacity_shift_calibration, prune,
               std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), c.table());
  if (c.best == cfg_.pipeline.triangles.opacity_shift) return;
  session_->set_opacity_shift(c.best);
  cfg_.pipeline.triangles.opacity_shift = c.best;
  config_yaml_ = config::to_yaml(cfg_);
  state_.config_yaml = config_yaml_;
  spdlog::info("opacity calibration: training with pipeline.triangles.opacity_shift {} (in config.yaml, the "
               "checkpoints and the model file)", c.best);
}

void Run::open_run_folder() {
  // Everything that reads user files has succeeded: only now does a new run
  // folder appear (a run that fails to start leaves nothing behind).
  if (rank0_) {
    if (mode_ == StartMode::overwrite) replace_run_folder(run_dir_.root);
    RunDir::create(run_dir_.root);
    setup_logging(cfg_.log.level, run_dir_.logs() + "/train.log");
    config::save_text(run_dir_.config_file(), config_yaml_);
    write_file_atomic(run_dir_.root + "/data_report.json", data_report_);
    metrics_ = std::make_unique<MetricsLog>(run_dir_.root, cfg_.log.tensorboard,
                                            mode_ == StartMode::resume ? state_.step : -1);
    best_.emplace(run_dir_.root, cfg_.validation.fall_warning_db, cfg_.optim.warmup_steps);
    if (mode_ == StartMode::resume) best_->resume();
  }
  log_run_start();
}

// What this run is: stage, steps, model, data and, with several ranks, the
// effective batch; loudly, when its latents come from a random encoder.
void Run::log_run_start() {
  const int64_t params = model::count_parameters(net());
  spdlog::info("flat_train: stage '{}' (task {}), steps {} to {}, run folder {}{}", cfg_.stage, cfg_.task, state_.step,
               cfg_.steps, run_dir_.root,
               summary_.last_checkpoint.empty() ? "" : " (resumed from " + summary_.last_checkpoint + ")");
  if (session_->vae_task())
    spdlog::info("Wan VAE: {:.3f} M parameters (dim {}, z_dim {}), frames {}x{}, windows of {}, device {}, precision {}; "
                 "loss {} L1 + {} L2 + {} LPIPS + {} KL",
                 double(params) / 1e6, cfg_.pipeline.model.vae.dim, cfg_.pipeline.model.vae.z_dim, cfg_.data.height,
                 cfg_.data.width, cfg_.data.input_frames, cfg_.device, bf16() ? "bf16 autocast" : "fp32", cfg_.vae.l1,
                 cfg_.vae.l2, cfg_.vae.lpips, cfg_.vae.kl);
  else
    spdlog::info("scene decoder: {:.3f} M parameters (dim {}, {} heads), device {}, precision {}, optimiser {} "
                 "(lr {:g}){}",
                 double(params) / 1e6, cfg_.pipeline.model.vae.dim, cfg_.pipeline.model.heads, cfg_.device,
                 bf16() ? "bf16 autocast" : "fp32", cfg_.optim.name, cfg_.optim.lr,
                 cfg_.pipeline.model.activation_checkpointing ? ", activation checkpointing" : "");
  for (const auto& line : data_summary_) spdlog::info("{}", line);
  if (!random_latents_.empty()) {
    spdlog::warn("=====================================================================");
    spdlog::warn("RANDOM-ENCODER LATENTS: {} hold latents of a random-weight encoder.", random_latents_);
    spdlog::warn("They carry almost nothing of the scene: the figures of this run are");
    spdlog::warn("pipeline checks, not results. Train a VAE (task: vae) or use Wan's.");
    spdlog::warn("=====================================================================");
  }
  if (dp_)
    spdlog::info("data parallel: {} ranks x data.batch_size {} per rank = effective batch {} (the learning rate is "
                 "not rescaled: docs/training.md), {} gradient bucket(s) of <= {} MB{}",
                 env_.world_size, cfg_.data.batch_size, cfg_.data.batch_size * env_.world_size, dp_->buckets(),
                 cfg_.distributed.bucket_mb, cfg_.distributed.overlap ? ", all-reduced during backward" : "");
}

void Run::run_validation(int64_t step) {
  if (!val_loader_) return;
  // Every rank scores its share of the scenes with its own weights: they must be rank 0's.
  if (dp_) dp_->check_weights_in_sync(net(), "step " + std::to_string(step));
  const auto t0 = std::chrono::steady_clock::now();
  auto r = session_->vae_task()
               ? validate_vae(session_->vae, *val_loader_, cfg_.validation.scenes, session_->vae_lpips,
                              cfg_.validation.grid_views, dp_ ? &dp_->group() : nullptr)
               : validate(*session_->pipeline, val_scenes_, val_settings_, session_->objective->lpips_network(),
                          cfg_.validation.grid_views, dp_ ? &dp_->group() : nullptr);
  raise_test_signal_in_validation(step);
  if (std::isnan(summary_.first_val_psnr)) summary_.first_val_psnr = r.psnr;
  summary_.last_val_psnr = r.psnr;
  summary_.mean_colour_psnr = r.mean_colour_psnr;
  if (!rank0_) return;
  metrics_->write("val", step, r.scalars());
  if (best_->record(step, r, session_->vae_task() ? "vae.safetensors" : "model.safetensors",
                    [&](const std::string& path) { write_model_file(path); }))
    spdlog::info("validation @ step {}: the best so far; weights in {}/best", step, run_dir_.root);
  std::string grid;
  if (r.grid.defined()) {
    char name[64];
    std::snprintf(name, sizeof(name), "/val_step_%08lld", static_cast<long long>(step));
    grid = write_preview_image(r.grid, run_dir_.renders() + name);
  }
  const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const std::string lp = std::isnan(r.lpips) ? "n/a" : fmt::format("{:.3f}", r.lpips);
  if (session_->vae_task())
    spdlog::info("validation @ step {}: reconstruction PSNR {:.2f} dB (mean-colour baseline {:.2f}), SSIM {:.3f}, "
                 "LPIPS {}; latents of different samples correlate {:.3f} on average; {} frames of {} held-out "
                 "windows ({:.1f} s){}",
                 step, r.psnr, r.mean_colour_psnr, r.ssim, lp, r.latent_correlation, r.views, r.samples, secs,
                 grid.empty() ? "" : "; grid " + grid);
  else
    spdlog::info("validation @ step {}: PSNR {:.2f} dB | baselines: mean colour {:.2f}, dataset mean {:.2f}, swap "
                 "{:.2f} | SSIM {:.3f}, LPIPS {}, normal cosine {:.3f}, depth SI-log {:.3f}, planar roughness "
                 "{:.4f} over {} views of {} held-out scenes ({:.1f} s){}{}",
                 step, r.psnr, r.mean_colour_psnr, r.dataset_mean_psnr, r.swap_psnr, r.ssim, lp, r.normal_cosine,
                 r.depth_si_log, r.planar_roughness, r.views, r.samples, secs, grid.empty() ? "" : "; grid " + grid,
                 random_latents_.empty() ? "" : " [RANDOM-ENCODER LATENTS: not a result]");
  summary_.swap_psnr = r.swap_psnr;
  summary_.dataset_mean_psnr = r.dataset_mean_psnr;
}

void Run::write_checkpoint() {
  if (!rank0_) return;
  summary_.last_checkpoint =
      save_checkpoint(run_dir_.checkpoints(), state_, net(), signature(), optimiser(), cfg_.checkpoint.keep);
  spdlog::info("checkpoint: {}", summary_.last_checkpoint);
}

Run::LoopEnd Run::train() {
  // A run resumed at or past its last step trains no more, but its final
  // file is written (again): a run stopped by a signal right at its end, or
  // resumed with --set steps=<its step>, still gets model.safetensors (or
  // vae.safetensors).
  const bool finished = state_.step >= cfg_.steps;
  if (finished) spdlog::info("flat_train: the run already did its {} steps; writing its final outputs", cfg_.steps);
  // Validation at the first step: step 0 of a new run; for a resumed run,
  // the one due right after its checkpoint (its row went with the lost work,
  // or was never written when the kill came during it): recomputed from the
  // same weights, so val.jsonl keeps every row.
  if (state_.step == 0 || (mode_ == StartMode::resume &&
                           (state_.step % cfg_.validation.every == 0 || state_.step == cfg_.steps)))
    run_validation(state_.step);

  // ---- the loop ------------------------------------------------------------------
  if (rank0_ && !finished) progress_.emplace(cfg_.stage, cfg_.steps - state_.step, cfg_.log.progress_seconds);
  while (state_.step < cfg_.steps) {
    const int64_t step = state_.step;
    const auto t0 = std::chrono::steady_clock::now();
    const StepOutcome out = take_step(step);
    count_step(step, out);
    state_.step = step + 1;
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (rank0_) write_step_metrics(step, out, seconds);

    const bool last = state_.step == cfg_.steps;
    const int stop = out.stop_signal;
    if (state_.step % cfg_.checkpoint.every == 0 || last || stop) write_checkpoint();
    if (stop) return stop_by_signal(stop);
    if (state_.step % cfg_.validation.every == 0 || last) run_validation(state_.step);
  }
  check_something_learned();
  if (progress_) progress_->finish();
  return LoopEnd::completed;
}

// One step on the next batch (debug.nan_steps poison it). With data
// parallelism every rank learns here whether any rank was asked to stop.
StepOutcome Run::take_step(int64_t step) {
  data::Batch batch = train_loader_->next();
  const auto& nan_steps = cfg_.debug.nan_steps;
  if (std::find(nan_steps.begin(), nan_steps.end(), step) != nan_steps.end())
    batch.video_latents.fill_(std::numeric_limits<float>::quiet_NaN());
  StepOutcome out = session_->step(batch, step, nullptr, stop_signal_requested());
  if (dp_ && step == summary_.first_step)
    spdlog::info("data parallel: {} of {} gradient buckets went out while backward ran (the rest after it)",
                 dp_->started_in_backward(), dp_->buckets());
  return out;
}

// The NaN guard: a skipped step is counted; nan_guard.max_consecutive in a
// row stop the run, its last good checkpoint intact.
void Run::count_step(int64_t step, const StepOutcome& out) {
  if (out.applied) {
    ++applied_steps_;
    state_.consecutive_skips = 0;
    return;
  }
  const StepResult& res = out.result;
  ++state_.skipped_steps;
  ++state_.consecutive_skips;
  spdlog::warn("step {}: non-finite {} ({}); step skipped ({} in a row, {} in all)", step,
               res.finite ? "gradient norm" : "loss", res.finite ? std::to_string(out.grad_norm) : res.nonfinite,
               state_.consecutive_skips, state_.skipped_steps);
  if (state_.consecutive_skips >= cfg_.nan_guard.max_consecutive) {
    if (progress_) progress_->abandon();
    fail("stopping: " + std::to_string(state_.consecutive_skips) +
         " consecutive steps had a non-finite loss or gradient (last: step " + std::to_string(step) +
         "). Check the data and the learning rate; the last good checkpoint is " +
         (summary_.last_checkpoint.empty() ? std::string("none yet") : summary_.last_checkpoint) +
         " (resume with --resume " + run_dir_.root + ")");
  }
}

// metrics/train.jsonl's row of the step, and the progress line (rank 0).
void Run::write_step_metrics(int64_t step, const StepOutcome& out, double seconds) {
  const StepResult& res = out.result;
  Scalars row = {{"loss", res.loss}};
  for (const auto& [name, value] : res.terms)
    if (name != "total") row.push_back({name, value});
  row.push_back({"lr", out.lr});
  row.push_back({"grad_norm", out.grad_norm});
  row.push_back({"skipped", out.applied ? 0.0 : 1.0});
  row.push_back({"triangles", double(res.triangles)});
  row.push_back({"step_seconds", seconds});
  if (device_.is_cuda()) row.push_back({"peak_memory_gib", peak_memory_gib(device_)});
  metrics_->write("train", step, row);
  progress_->step(1, {{"loss", res.loss}, {"rgb", res.terms.count("rgb") ? res.terms.at("rgb") : NAN}, {"lr", out.lr}});
}

// After the stop request's checkpoint: the summary says how to continue.
Run::LoopEnd Run::stop_by_signal(int stop) {
  if (progress_) progress_->abandon();
  spdlog::warn("flat_train: stopped by signal {} after step {}; continue with: flat_train --resume {}", stop,
               state_.step, run_dir_.root);
  summary_.exit_code = 128 + stop;
  summary_.steps_done = state_.step;
  summary_.skipped_steps = state_.skipped_steps;
  return LoopEnd::stopped_by_signal;
}

// A session whose every step was skipped learned nothing: not a success,
// and no final model file (its checkpoints hold the unchanged weights).
void Run::check_something_learned() {
  if (state_.step > summary_.first_step && applied_steps_ == 0) {
    if (progress_) progress_->abandon();
    fail("every one of the " + std::to_string(state_.step - summary_.first_step) + " steps of this session (" +
         std::to_string(summary_.first_step) + " to " + std::to_string(state_.step - 1) +
         ") had a non-finite loss or gradient and was skipped: nothing was learned, no final model written. Check "
         "the data and the learning rate; the last good checkpoint is " +
         (summary_.last_checkpoint.empty() ? std::string("none") : summary_.last_checkpoint));
  }
}

// The weights as flat_infer / flat_latents read them: model.safetensors (Wan
// key names, the architecture signature), or for the VAE task the Wan VAE
// file with the training windows' latent statistics folded in.
void Run::write_model_file(const std::string& path) {
  if (session_->vae_task()) {
    data::LoaderConfig stats_data = train_data_;
    stats_data.batch_size = 1;
    stats_data.workers = 0;
    data::Loader stats_loader(stats_data);
    const auto stats = measure_latent_statistics(session_->vae, stats_loader, cfg_.vae.stats_samples);
    write_vae_file(session_->vae, stats, path,
                   {{"producer", "flat_train"}, {"stage", cfg_.stage}, {"task", "vae"},
                    {"step", std::to_string(state_.step)}});
    spdlog::info("flat_train: VAE written to {} (Wan 2.1 key names; latent mean {:.3f}..{:.3f}, std {:.3f}..{:.3f} "
                 "over {} training windows, folded in)",
                 path, stats.mean.min().item<double>(), stats.mean.max().item<double>(),
                 stats.std.min().item<double>(), stats.std.max().item<double>(), stats.samples);
  } else {
    auto meta = pipeline::signature_metadata(signature());
    meta.insert({{"producer", "flat_train"}, {"stage", cfg_.stage}, {"step", std::to_string(state_.step)}});
    if (!random_latents_.empty()) meta.insert({{"latent_encoder", "random"}});
    model::save_weights(net(), path, model::WeightNaming::wan, meta);
  }
}

// ---- the end -------------------------------------------------------------------
TrainSummary Run::finish(LoopEnd end) {
  // Stopped by a signal: its checkpoint is written and the summary says so
  // (train()); no final model file.
  if (end == LoopEnd::stopped_by_signal) return end_ranks();
  summary_.steps_done = state_.step;
  summary_.skipped_steps = state_.skipped_steps;
  if (!rank0_) return end_ranks();
  summary_.model_file = run_dir_.root + (session_->vae_task() ? "/vae.safetensors" : "/model.safetensors");
  write_model_file(summary_.model_file);
  spdlog::info("flat_train: stage '{}' finished: {} steps ({} skipped as non-finite)", cfg_.stage, state_.step,
               state_.skipped_steps);
  if (!std::isnan(summary_.last_val_psnr)) {
    if (session_->vae_task())
      spdlog::info("held-out reconstruction PSNR: {:.2f} dB -> {:.2f} dB (mean-colour baseline {:.2f} dB)",
                   summary_.first_val_psnr, summary_.last_val_psnr, summary_.mean_colour_psnr);
    else
      spdlog::info("held-out PSNR: {:.2f} dB -> {:.2f} dB | baselines: mean colour {:.2f} dB, dataset mean {:.2f} dB, "
                   "swap {:.2f} dB{}",
                   summary_.first_val_psnr, summary_.last_val_psnr, summary_.mean_colour_psnr,
                   summary_.dataset_mean_psnr, summary_.swap_psnr,
                   random_latents_.empty() ? "" : " [RANDOM-ENCODER LATENTS: not a result]");
    if (best_ && best_->best_step() >= 0)
      spdlog::info("best held-out PSNR {:.2f} dB at step {} ({}/best){}", best_->best_psnr(), best_->best_step(),
                   run_dir_.root,
                   best_->falls() ? fmt::format("; {} validation(s) of this session fell more than {} dB below the "
                                                "best (logs/val_falls.jsonl)",
                                                best_->falls(), cfg_.validation.fall_warning_db)
                                  : "");
  }
  spdlog::info("outputs: {} (config.yaml, logs/train.log, metrics/*.jsonl, tensorboard/, renders/, checkpoints/, "
               "{})",
               run_dir_.root, session_->vae_task() ? "vae.safetensors" : "model.safetensors");
  return end_ranks();
}

// The clean end on every rank (not after an error: a peer may be gone).
// The peak GPU memory of every rank is logged by rank 0 (what a cluster job
// must fit in per GPU).
TrainSummary Run::end_ranks() {
  if (device_.is_cuda()) {
    std::vector<double> peaks(size_t(env_.world_size), 0.0);
    peaks[size_t(env_.rank)] = peak_memory_gib(device_);
    if (dp_) peaks = dp_->sum(peaks);
    std::string list;
    for (size_t r = 0; r < peaks.size(); ++r) list += fmt::format("{}{:.2f}", r ? ", " : "", peaks[r]);
    spdlog::info("peak GPU memory (GiB, caching allocator) of rank 0..{}: {}", peaks.size() - 1, list);
  }
  if (dp_) dp_->finish();
  return summary_;
}

}  // namespace

TrainSummary run_training(const TrainConfig& cfg, const std::string& config_yaml, StartMode mode,
                          const distributed::DistributedEnv& env) {
  Run run(cfg, config_yaml, mode, env);
  run.start_ranks();
  run.start_session();
  if (const char* s = std::getenv(kSignalInStartupEnv)) std::raise(std::atoi(s));
  run.resume_or_start_fresh();
  run.open_loaders();
  run.calibrate_opacity_shift();
  run.open_run_folder();
  const Run::LoopEnd end = run.train();
  return run.finish(end);
}

}  // namespace flat::train
