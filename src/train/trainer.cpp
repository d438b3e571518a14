#include "flat/train/trainer.h"

#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <optional>

#include <c10/core/impl/DeviceGuardImplInterface.h>
#include <spdlog/sinks/stdout_color_sinks.h>

#include <torch/torch.h>

#include "flat/core/device_memory.h"
#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/log.h"
#include "flat/core/progress.h"
#include "flat/core/run_dir.h"
#include "flat/model/weights.h"
#include "flat/optim/adamw.h"
#include "flat/train/checkpoint.h"
#include "flat/train/data_parallel.h"
#include "flat/train/lr_schedule.h"
#include "flat/train/metrics_log.h"
#include "flat/train/train_step.h"
#include "flat/train/training_session.h"
#include "flat/train/validation.h"

namespace flat::train {
namespace fs = std::filesystem;

namespace {

// ---- stop signals ------------------------------------------------------------
// The first SIGINT/SIGTERM asks the loop to stop after the current step and
// write a checkpoint; a second one ends the process at once (default action).
// One request often arrives twice: coreutils `timeout` signals the command
// and then its process group, a scheduler signals every process of a job
// step and a terminal its process group, a launcher (flat_train --nproc,
// torchrun) forwards what its rank also got directly. A repeat within a
// second is therefore the same request; a later one still ends the process.
// (Before this, a single-process run under `timeout` lost its checkpoint
// whenever the two copies arrived apart: GPU recipe, 2026-11-26.)
std::atomic<int> g_stop_signal{0};
std::atomic<int64_t> g_first_signal_ms{0};

int64_t monotonic_ms() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);  // async-signal-safe
  return int64_t(ts.tv_sec) * 1000 + ts.tv_nsec / 1000000;
}

extern "C" void on_stop_signal(int sig) {
  if (g_stop_signal.load() == 0) {
    g_first_signal_ms.store(monotonic_ms());
    g_stop_signal.store(sig);
    return;
  }
  if (monotonic_ms() - g_first_signal_ms.load() < 1000) return;
  std::signal(sig, SIG_DFL);
  std::raise(sig);
}

// SIGHUP (a closed terminal or SSH session) is a stop request too.
struct StopSignals {
  using Handler = void (*)(int);
  Handler old_int, old_term, old_hup;
  StopSignals() {
    g_stop_signal.store(0);
    old_int = std::signal(SIGINT, on_stop_signal);
    old_term = std::signal(SIGTERM, on_stop_signal);
    old_hup = std::signal(SIGHUP, on_stop_signal);
  }
  ~StopSignals() {
    std::signal(SIGINT, old_int);
    std::signal(SIGTERM, old_term);
    std::signal(SIGHUP, old_hup);
  }
};

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

// The test hook of kSignalInValidationEnv: "<step>" or "<step>:<signal>".
void signal_for_test(int64_t step) {
  const char* v = std::getenv(kSignalInValidationEnv);
  if (!v) return;
  const std::string text = v;
  const auto colon = text.find(':');
  if (text.substr(0, colon) != std::to_string(step)) return;
  std::raise(colon == std::string::npos ? SIGKILL : std::atoi(text.c_str() + colon + 1));
}

// checkpoints/step_00000040 -> 40.
int64_t ckpt_step(const std::string& dir) {
  const std::string name = fs::path(dir).filename().string();
  return std::stoll(name.substr(name.find('_') + 1));
}


bool holds_a_run(const std::string& dir) {
  std::error_code ec;
  for (const char* entry : {"config.yaml", "checkpoints", "metrics", "model.safetensors"})
    if (fs::exists(fs::path(dir) / entry, ec)) return true;
  return false;
}

// What --overwrite may replace: a folder that is recognisably a run of
// flat_train (its config.yaml beside at least one of the folders a run
// makes), or an empty one. Anything else may be the user's own files.
bool is_run_folder(const std::string& dir) {
  std::error_code ec;
  if (fs::is_empty(dir, ec) && !ec) return true;
  if (!fs::is_regular_file(fs::path(dir) / "config.yaml", ec)) return false;
  for (const char* sub : {"checkpoints", "logs", "metrics"})
    if (fs::is_directory(fs::path(dir) / sub, ec)) return true;
  return false;
}

// Checks made before anything is loaded; nothing is changed here. An
// --overwrite'd run folder is only replaced by replace_run_folder, once the
// new run has loaded everything.
void check_run_folder(const std::string& dir, StartMode mode) {
  std::error_code ec;
  if (mode == StartMode::fresh && holds_a_run(dir)) {
    const auto n = list_checkpoints(dir + "/checkpoints").size();
    fail("run folder '" + dir + "' already holds a run (" + std::to_string(n) +
         " checkpoint(s)): continue it with --resume " + dir + ", start it over with --overwrite, or choose another "
         "run_dir");
  }
  if (mode == StartMode::overwrite && fs::exists(dir, ec)) {
    FLAT_CHECK(fs::is_directory(dir, ec), "run folder '" + dir + "' exists and is not a folder");
    if (!is_run_folder(dir))
      fail("run folder '" + dir + "' is not a flat_train run folder (no config.yaml beside checkpoints/, logs/ or "
           "metrics/); --overwrite replaces only a run folder, so nothing in it was touched: choose another "
           "run_dir, or move its files away yourself");
  }
}

// --overwrite: the old run folder goes only now, when the new run has loaded
// its config, data and model and is about to write: it is renamed aside
// (one rename, so a failure before it left the old run whole), then deleted.
void replace_run_folder(const std::string& dir) {
  std::error_code ec;
  if (!fs::exists(dir, ec)) return;
  if (!is_run_folder(dir))  // checked at the start; it may have changed since
    fail("run folder '" + dir + "' is no longer a flat_train run folder; --overwrite left it as it is");
  std::string root = dir;
  while (root.size() > 1 && root.back() == '/') root.pop_back();
  const std::string old = root + ".old-" + std::to_string(::getpid());
  fs::rename(root, old, ec);
  if (ec) fail("run folder '" + dir + "': cannot move the old run aside for --overwrite (" + ec.message() + ")");
  fs::remove_all(old, ec);
  if (ec) spdlog::warn("--overwrite: the old run was moved to {} but cannot be deleted ({})", old, ec.message());
}

}  // namespace

TrainConfig load_run_config(const std::string& run_dir, const std::vector<std::string>& overrides,
                            std::string* effective_yaml) {
  const std::string file = run_dir + "/config.yaml";
  std::error_code ec;
  if (!fs::exists(file, ec))
    fail(run_dir + ": no config.yaml; is this a run folder of flat_train? (--resume takes the run folder)");
  std::vector<std::string> all = {"run_dir=" + run_dir};  // the folder may have moved since
  all.insert(all.end(), overrides.begin(), overrides.end());
  auto cfg = config::load<TrainConfig>(file, all);
  if (effective_yaml) *effective_yaml = config::to_yaml(cfg);
  return cfg;
}

TrainSummary run_training(const TrainConfig& cfg, const std::string& config_yaml, StartMode mode,
                          const distributed::DistributedEnv& env) {
  // Data parallelism: rank 0 alone touches the run folder (logs, metrics,
  // TensorBoard, checkpoints, validation grids, the final model); the other
  // ranks log warnings and errors to stderr with their rank.
  const bool root = env.rank == 0;
  if (root) {
    check_run_folder(cfg.run_dir, mode);
    setup_logging(cfg.log.level);
  } else {
    setup_rank_logging(cfg.log.level, env);
  }
  // From here to the end a stop request is honoured: one that comes during
  // start-up or a validation is acted on after the next step (a checkpoint,
  // then exit 128 + signal).
  StopSignals signals;
  TrainSummary summary;
  summary.run_dir = cfg.run_dir;
  const RunDir run{cfg.run_dir};  // paths only: created once everything below has loaded

  if (cfg.threads > 0) at::set_num_threads(int(cfg.threads));
  torch::manual_seed(uint64_t(cfg.seed));

  // ---- ranks ---------------------------------------------------------------------
  // One GPU per rank: cuda:LOCAL_RANK, the current device before NCCL starts
  // (kernels launched without a device of their own go there too).
  at::Device device(cfg.device == "cuda" ? at::kCUDA : at::kCPU);
  if (device.is_cuda() && env.distributed()) {
    device = at::Device(at::kCUDA, static_cast<c10::DeviceIndex>(env.local_rank));
    const int64_t gpus = torch::cuda::is_available() ? int64_t(torch::cuda::device_count()) : 0;
    FLAT_CHECK(env.local_rank < gpus, "distributed: rank " + std::to_string(env.rank) + " has LOCAL_RANK " +
                                          std::to_string(env.local_rank) + " but this host shows " +
                                          std::to_string(gpus) + " CUDA device(s): start at most that many ranks "
                                          "per host (--nproc, --nproc-per-node) or check CUDA_VISIBLE_DEVICES");
    c10::impl::getDeviceGuardImpl(at::kCUDA)->setDevice(device);
  }
  std::unique_ptr<DataParallel> dp;
  if (env.distributed()) {
    dp = std::make_unique<DataParallel>(cfg.distributed, env, device);
    spdlog::info("distributed: rank {} of {} on {}, backend {}, timeout {} s", env.rank, env.world_size,
                 device.str(), dp->backend(), cfg.distributed.timeout_seconds);
  }

  // ---- model, objective, optimiser ------------------------------------------------
  TrainingSession session(cfg, device);
  torch::nn::Module& net = session.model();  // the trained module
  auto& optimiser = *session.optimiser;
  const ModelSignature& signature = session.signature;
  const bool bf16 = session.bf16;

  // ---- resume ------------------------------------------------------------------
  TrainerState state;
  state.stage = cfg.stage;
  state.config_yaml = config_yaml;
  if (mode == StartMode::resume) {
    // Rank 0 picks the newest intact checkpoint (clearing a half-written one,
    // naming and setting aside broken ones); every rank loads it.
    std::optional<LoadedCheckpoint> loaded;
    if (root) loaded = load_newest_intact_checkpoint(run.checkpoints());
    std::string latest = loaded ? loaded->dir : std::string();
    if (dp) {
      const int64_t step = dp->broadcast(latest.empty() ? -1 : ckpt_step(latest));
      latest = step < 0 ? std::string() : checkpoint_folder(run.checkpoints(), step);
    }
    if (latest.empty()) {
      spdlog::warn("resume: '{}' has no checkpoint yet; starting the stage from step 0", run.root);
    } else {
      auto ckpt = loaded ? std::move(*loaded) : read_checkpoint(latest);
      load_model_weights(net, ckpt.model, ckpt.signature, signature, latest + "/model.safetensors");
      optimiser.load_state(ckpt.optimiser, latest + "/optimizer.safetensors");
      restore_rng(ckpt.rng, latest + "/rng.safetensors");
      state.step = ckpt.state.step;
      state.skipped_steps = ckpt.state.skipped_steps;
      state.consecutive_skips = ckpt.state.consecutive_skips;
      summary.last_checkpoint = latest;
      spdlog::info("resume: {} at step {} of {}", latest, state.step, cfg.steps);
    }
  }
  summary.first_step = state.step;
  if (dp) {
    // Every rank starts from rank 0's weights (the same seed and checkpoint
    // give them already; this makes sure), then averages its gradients.
    dp->share_weights(net);
    session.use_data_parallel(dp.get());
  }

  // ---- data --------------------------------------------------------------------
  // data.batch_size is the global batch: rank r of W loads B/W of each, the
  // samples (b*W + r)*B/W ... of the stream, so the W shares together are the
  // batch one process would load (loader.h).
  data::LoaderConfig train_data = cfg.data;
  train_data.camera_rays = cfg.pipeline.model.camera_rays;  // the camera latents the model reads
  if (dp) {
    FLAT_CHECK(cfg.data.batch_size % env.world_size == 0,
               "data.batch_size " + std::to_string(cfg.data.batch_size) + " is the global batch and must be a "
               "multiple of the " + std::to_string(env.world_size) + " ranks");
    train_data.batch_size = cfg.data.batch_size / env.world_size;
  }
  data::Loader loader(train_data, state.step, env.rank, env.world_size);
  std::unique_ptr<data::Loader> val_loader;
  if (!cfg.validation.datasets.empty()) {
    data::LoaderConfig v = cfg.data;
    v.datasets = cfg.validation.datasets;
    v.camera_rays = cfg.pipeline.model.camera_rays;
    v.batch_size = 1;
    v.workers = 0;
    v.seed = 1000003;  // fixed: the same held-out views at every validation
    v.skip_bad_scenes = false;
    val_loader = std::make_unique<data::Loader>(v);
  } else {
    spdlog::warn("validation: no held-out datasets (validation.datasets); no validation metrics");
  }
  // Provenance: latents of a random-weight encoder carry almost nothing of the
  // scene; every figure made from them says so.
  std::string random_latents;
  if (!session.vae_task()) {
    for (const auto* l : {&loader, val_loader.get()}) {
      if (!l) continue;
      const auto enc = l->latent_encoders();
      if (enc.count("random"))
        random_latents += (random_latents.empty() ? "" : "; ") + std::to_string(enc.at("random")) + " of " +
                          std::to_string(l->scene_count()) + (l == &loader ? " training" : " held-out") + " scenes";
    }
  }
  // The "same output for every scene" baseline: the training set's mean image.
  at::Tensor dataset_mean;
  if (val_loader && !session.vae_task()) dataset_mean = training_mean_image(cfg.data, 32);
  // Everything that reads user files has succeeded: only now does a new run
  // folder appear (a run that fails to start leaves nothing behind).
  std::unique_ptr<MetricsLog> metrics;
  if (root) {
    if (mode == StartMode::overwrite) replace_run_folder(run.root);
    RunDir::create(run.root);
    setup_logging(cfg.log.level, run.logs() + "/train.log");
    config::save_text(run.config_file(), config_yaml);
    metrics = std::make_unique<MetricsLog>(run.root, cfg.log.tensorboard, mode == StartMode::resume ? state.step : -1);
  }
  const int64_t params = model::count_parameters(net);
  spdlog::info("flat_train: stage '{}' (task {}), steps {} to {}, run folder {}{}", cfg.stage, cfg.task, state.step,
               cfg.steps, run.root,
               summary.last_checkpoint.empty() ? "" : " (resumed from " + summary.last_checkpoint + ")");
  if (session.vae_task())
    spdlog::info("Wan VAE: {:.3f} M parameters (dim {}, z_dim {}), frames {}x{}, windows of {}, device {}, precision {}; "
                 "loss {} L1 + {} L2 + {} LPIPS + {} KL",
                 double(params) / 1e6, cfg.pipeline.model.vae.dim, cfg.pipeline.model.vae.z_dim, cfg.data.height,
                 cfg.data.width, cfg.data.input_frames, cfg.device, bf16 ? "bf16 autocast" : "fp32", cfg.vae.l1,
                 cfg.vae.l2, cfg.vae.lpips, cfg.vae.kl);
  else
    spdlog::info("scene decoder: {:.3f} M parameters (dim {}, {} heads), device {}, precision {}", double(params) / 1e6,
                 cfg.pipeline.model.vae.dim, cfg.pipeline.model.heads, cfg.device, bf16 ? "bf16 autocast" : "fp32");
  if (!random_latents.empty()) {
    spdlog::warn("=====================================================================");
    spdlog::warn("RANDOM-ENCODER LATENTS: {} hold latents of a random-weight encoder.", random_latents);
    spdlog::warn("They carry almost nothing of the scene: the figures of this run are");
    spdlog::warn("pipeline checks, not results. Train a VAE (task: vae) or use Wan's.");
    spdlog::warn("=====================================================================");
  }
  if (dp)
    spdlog::info("data parallel: {} ranks, global batch {} ({} per rank), {} gradient bucket(s) of <= {} MB{}",
                 env.world_size, cfg.data.batch_size, train_data.batch_size, dp->buckets(),
                 cfg.distributed.bucket_mb, cfg.distributed.overlap ? ", all-reduced during backward" : "");

  auto run_validation = [&](int64_t step) {
    if (!val_loader) return;
    const auto t0 = std::chrono::steady_clock::now();
    auto r = session.vae_task()
                 ? validate_vae(session.vae, *val_loader, cfg.validation.scenes, session.vae_lpips,
                                cfg.validation.grid_views, dp ? &dp->group() : nullptr)
                 : validate(*session.pipeline, *val_loader, cfg.validation.scenes, session.objective->lpips_network(),
                            cfg.validation.grid_views, dp ? &dp->group() : nullptr, dataset_mean, bf16);
    signal_for_test(step);
    if (std::isnan(summary.first_val_psnr)) summary.first_val_psnr = r.psnr;
    summary.last_val_psnr = r.psnr;
    summary.mean_colour_psnr = r.mean_colour_psnr;
    if (!root) return;
    metrics->write("val", step, r.scalars());
    std::string grid;
    if (r.grid.defined()) {
      char name[64];
      std::snprintf(name, sizeof(name), "/val_step_%08lld", static_cast<long long>(step));
      grid = write_preview_image(r.grid, run.renders() + name);
    }
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const std::string lp = std::isnan(r.lpips) ? "n/a" : fmt::format("{:.3f}", r.lpips);
    if (session.vae_task())
      spdlog::info("validation @ step {}: reconstruction PSNR {:.2f} dB (mean-colour baseline {:.2f}), SSIM {:.3f}, "
                   "LPIPS {}; latents of different samples correlate {:.3f} on average; {} frames of {} held-out "
                   "windows ({:.1f} s){}",
                   step, r.psnr, r.mean_colour_psnr, r.ssim, lp, r.latent_correlation, r.views, r.samples, secs,
                   grid.empty() ? "" : "; grid " + grid);
    else
      spdlog::info("validation @ step {}: PSNR {:.2f} dB | baselines: mean colour {:.2f}, dataset mean {:.2f}, swap "
                   "{:.2f} | SSIM {:.3f}, LPIPS {}, normal cosine {:.3f} over {} views of {} held-out samples "
                   "({:.1f} s){}{}",
                   step, r.psnr, r.mean_colour_psnr, r.dataset_mean_psnr, r.swap_psnr, r.ssim, lp, r.normal_cosine,
                   r.views, r.samples, secs, grid.empty() ? "" : "; grid " + grid,
                   random_latents.empty() ? "" : " [RANDOM-ENCODER LATENTS: not a result]");
    summary.swap_psnr = r.swap_psnr;
    summary.dataset_mean_psnr = r.dataset_mean_psnr;
  };
  auto write_checkpoint = [&] {
    if (!root) return;
    summary.last_checkpoint =
        save_checkpoint(run.checkpoints(), state, net, signature, optimiser, cfg.checkpoint.keep);
    spdlog::info("checkpoint: {}", summary.last_checkpoint);
  };
  // The clean end on every rank (not after an error: a peer may be gone).
  // The peak GPU memory of every rank is logged by rank 0 (what a cluster job
  // must fit in per GPU).
  auto finish = [&] {
    if (device.is_cuda()) {
      std::vector<double> peaks(size_t(env.world_size), 0.0);
      peaks[size_t(env.rank)] = peak_memory_gib(device);
      if (dp) peaks = dp->sum(peaks);
      std::string list;
      for (size_t r = 0; r < peaks.size(); ++r) list += fmt::format("{}{:.2f}", r ? ", " : "", peaks[r]);
      spdlog::info("peak GPU memory (GiB, caching allocator) of rank 0..{}: {}", peaks.size() - 1, list);
    }
    if (dp) dp->finish();
    return summary;
  };

  // A run resumed at or past its last step trains no more, but its final
  // file is written (again): a run stopped by a signal right at its end, or
  // resumed with --set steps=<its step>, still gets model.safetensors (or
  // vae.safetensors).
  const bool finished = state.step >= cfg.steps;
  if (finished) spdlog::info("flat_train: the run already did its {} steps; writing its final outputs", cfg.steps);
  // Validation at the first step: step 0 of a new run; for a resumed run,
  // the one due right after its checkpoint (its row went with the lost work,
  // or was never written when the kill came during it): recomputed from the
  // same weights, so val.jsonl keeps every row.
  if (state.step == 0 || (mode == StartMode::resume &&
                          (state.step % cfg.validation.every == 0 || state.step == cfg.steps)))
    run_validation(state.step);

  // ---- the loop ------------------------------------------------------------------
  std::optional<Progress> progress;
  int64_t applied_steps = 0;  // of this session
  if (root && !finished) progress.emplace(cfg.stage, cfg.steps - state.step, cfg.log.progress_seconds);
  while (state.step < cfg.steps) {
    const int64_t step = state.step;
    const auto t0 = std::chrono::steady_clock::now();
    data::Batch batch = loader.next();
    const auto& nan_steps = cfg.debug.nan_steps;
    if (std::find(nan_steps.begin(), nan_steps.end(), step) != nan_steps.end())
      batch.video_latents.fill_(std::numeric_limits<float>::quiet_NaN());

    // With data parallelism every rank learns here whether any rank was asked to stop.
    StepOutcome out = session.step(batch, step, nullptr, g_stop_signal.load());
    const StepResult& res = out.result;
    const double lr = out.lr, grad_norm = out.grad_norm;
    const bool ok = out.applied;
    if (dp && step == summary.first_step)
      spdlog::info("data parallel: {} of {} gradient buckets went out while backward ran (the rest after it)",
                   dp->started_in_backward(), dp->buckets());
    if (ok) {
      ++applied_steps;
      state.consecutive_skips = 0;
    } else {
      ++state.skipped_steps;
      ++state.consecutive_skips;
      spdlog::warn("step {}: non-finite {} ({}); step skipped ({} in a row, {} in all)", step,
                   res.finite ? "gradient norm" : "loss", res.finite ? std::to_string(grad_norm) : res.nonfinite,
                   state.consecutive_skips, state.skipped_steps);
      if (state.consecutive_skips >= cfg.nan_guard.max_consecutive) {
        if (progress) progress->abandon();
        fail("stopping: " + std::to_string(state.consecutive_skips) +
             " consecutive steps had a non-finite loss or gradient (last: step " + std::to_string(step) +
             "). Check the data and the learning rate; the last good checkpoint is " +
             (summary.last_checkpoint.empty() ? std::string("none yet") : summary.last_checkpoint) +
             " (resume with --resume " + run.root + ")");
      }
    }
    state.step = step + 1;
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();

    if (root) {
      Scalars row = {{"loss", res.loss}};
      for (const auto& [name, value] : res.terms)
        if (name != "total") row.push_back({name, value});
      row.push_back({"lr", lr});
      row.push_back({"grad_norm", grad_norm});
      row.push_back({"skipped", ok ? 0.0 : 1.0});
      row.push_back({"triangles", double(res.triangles)});
      row.push_back({"step_seconds", seconds});
      if (device.is_cuda()) row.push_back({"peak_memory_gib", peak_memory_gib(device)});
      metrics->write("train", step, row);
      progress->step(1, {{"loss", res.loss}, {"rgb", res.terms.count("rgb") ? res.terms.at("rgb") : NAN}, {"lr", lr}});
    }

    const bool last = state.step == cfg.steps;
    const int stop = out.stop_signal;
    if (state.step % cfg.checkpoint.every == 0 || last || stop) write_checkpoint();
    if (stop) {
      if (progress) progress->abandon();
      spdlog::warn("flat_train: stopped by signal {} after step {}; continue with: flat_train --resume {}", stop,
                   state.step, run.root);
      summary.exit_code = 128 + stop;
      summary.steps_done = state.step;
      summary.skipped_steps = state.skipped_steps;
      return finish();
    }
    if (state.step % cfg.validation.every == 0 || last) run_validation(state.step);
  }
  // A session whose every step was skipped learned nothing: not a success,
  // and no final model file (its checkpoints hold the unchanged weights).
  if (state.step > summary.first_step && applied_steps == 0) {
    if (progress) progress->abandon();
    fail("every one of the " + std::to_string(state.step - summary.first_step) + " steps of this session (" +
         std::to_string(summary.first_step) + " to " + std::to_string(state.step - 1) +
         ") had a non-finite loss or gradient and was skipped: nothing was learned, no final model written. Check "
         "the data and the learning rate; the last good checkpoint is " +
         (summary.last_checkpoint.empty() ? std::string("none") : summary.last_checkpoint));
  }
  if (progress) progress->finish();

  // ---- the end -------------------------------------------------------------------
  summary.steps_done = state.step;
  summary.skipped_steps = state.skipped_steps;
  if (!root) return finish();
  if (session.vae_task()) {
    // The latent statistics of the training windows, folded into the file
    // that flat_latents, flat_vae and init.from: wan_vae read.
    data::LoaderConfig stats_data = train_data;
    stats_data.batch_size = 1;
    stats_data.workers = 0;
    data::Loader stats_loader(stats_data);
    const auto stats = measure_latent_statistics(session.vae, stats_loader, cfg.vae.stats_samples);
    summary.model_file = run.root + "/vae.safetensors";
    write_vae_file(session.vae, stats, summary.model_file,
                   {{"producer", "flat_train"}, {"stage", cfg.stage}, {"task", "vae"},
                    {"step", std::to_string(state.step)}});
    spdlog::info("flat_train: VAE written to {} (Wan 2.1 key names; latent mean {:.3f}..{:.3f}, std {:.3f}..{:.3f} "
                 "over {} training windows, folded in)",
                 summary.model_file, stats.mean.min().item<double>(), stats.mean.max().item<double>(),
                 stats.std.min().item<double>(), stats.std.max().item<double>(), stats.samples);
  } else {
    summary.model_file = run.root + "/model.safetensors";
    auto meta = pipeline::signature_metadata(signature);
    meta.insert({{"producer", "flat_train"}, {"stage", cfg.stage}, {"step", std::to_string(state.step)}});
    if (!random_latents.empty()) meta.insert({{"latent_encoder", "random"}});
    model::save_weights(net, summary.model_file, model::WeightNaming::wan, meta);
  }
  spdlog::info("flat_train: stage '{}' finished: {} steps ({} skipped as non-finite)", cfg.stage, state.step,
               state.skipped_steps);
  if (!std::isnan(summary.last_val_psnr)) {
    if (session.vae_task())
      spdlog::info("held-out reconstruction PSNR: {:.2f} dB -> {:.2f} dB (mean-colour baseline {:.2f} dB)",
                   summary.first_val_psnr, summary.last_val_psnr, summary.mean_colour_psnr);
    else
      spdlog::info("held-out PSNR: {:.2f} dB -> {:.2f} dB | baselines: mean colour {:.2f} dB, dataset mean {:.2f} dB, "
                   "swap {:.2f} dB{}",
                   summary.first_val_psnr, summary.last_val_psnr, summary.mean_colour_psnr, summary.dataset_mean_psnr,
                   summary.swap_psnr, random_latents.empty() ? "" : " [RANDOM-ENCODER LATENTS: not a result]");
  }
  spdlog::info("outputs: {} (config.yaml, logs/train.log, metrics/*.jsonl, tensorboard/, renders/, checkpoints/, "
               "{})",
               run.root, session.vae_task() ? "vae.safetensors" : "model.safetensors");
  return finish();
}

}  // namespace flat::train
