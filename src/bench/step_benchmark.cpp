#include "flat/bench/step_benchmark.h"
#include "flat/bench/gpu_profile.h"
#include "flat/bench/timing.h"

#include <algorithm>
#include <chrono>
#include <cstdio>

#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/core/device_memory.h"
#include "flat/core/error.h"
#include "flat/core/tensor_io.h"
#include "flat/loss/lpips.h"
#include "flat/model/weights.h"
#include "flat/train/training_session.h"

namespace flat::bench {

using namespace flat::train;

namespace {

using Clock = std::chrono::steady_clock;

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

void sync(const at::Device& d) { sync_device(d); }

std::string row(const char* name, double ms, double step_ms) {
  char buf[160];
  std::snprintf(buf, sizeof(buf), "| %s | %.1f | %.0f%% |\n", name, ms, step_ms > 0 ? 100 * ms / step_ms : 0.0);
  return buf;
}

const char* const kPhases[] = {"decoder forward", "rasterizer forward", "losses forward",
                                "losses + rasterizer backward", "decoder backward", "optimiser and the rest"};

// The GPU kernels of one step by phase: each phase ended with a device
// synchronisation (StepTimes::phase_end_ns), so a kernel belongs to the first
// phase that ended after it did.
void print_step_profile(const std::vector<GpuActivity>& acts, const StepTimes& times) {
  const double wall[] = {times.decode_forward, times.render_forward, times.loss_forward, times.render_loss_backward,
                         times.decoder_backward};
  if (times.phase_end_ns.size() != std::size(wall)) {
    // A step without the five phases (the VAE task, or one stopped by a
    // non-finite loss): the whole step as one group.
    print_grouped("profile, whole step, by class", acts, 12, kernel_class);
    print_grouped("profile, whole step, by kernel", acts, 16, [](const std::string& n) { return n.substr(0, 100); });
    return;
  }
  std::vector<std::vector<GpuActivity>> by_phase(std::size(kPhases));
  for (const auto& a : acts) {
    size_t p = 0;
    while (p < times.phase_end_ns.size() && a.end_ns > times.phase_end_ns[p]) ++p;
    by_phase[p].push_back(a);
  }
  for (size_t p = 0; p < by_phase.size(); ++p) {
    if (by_phase[p].empty()) continue;
    std::string title = std::string("profile, ") + kPhases[p];
    if (p < std::size(wall)) title += " (" + std::to_string(int(wall[p] * 1e3 + 0.5)) + " ms wall, profiled)";
    print_grouped(title + ", by class", by_phase[p], 12, kernel_class);
    print_grouped(title + ", by kernel", by_phase[p], 12, [](const std::string& n) { return n.substr(0, 100); });
  }
}

}  // namespace

std::string StepBenchmark::table() const {
  std::string t = "| part | ms (median) | share |\n|---|---|---|\n";
  t += row("data (loader wait)", data_ms, step_ms);
  t += row("decoder forward (incl. triangle builder)", decode_forward_ms, step_ms);
  t += row("rasterizer forward", render_forward_ms, step_ms);
  t += row("losses forward (incl. LPIPS)", loss_forward_ms, step_ms);
  t += row("losses + rasterizer backward", render_loss_backward_ms, step_ms);
  t += row("decoder backward", decoder_backward_ms, step_ms);
  t += row("grad norm, clip, AdamW", optimiser_ms, step_ms);
  t += row("whole step (phases synchronised)", step_ms, step_ms);
  char buf[200];
  std::snprintf(buf, sizeof(buf), "| whole step as trained (no phase syncs) | %.1f | %.2f it/s |\n", unsynced_step_ms,
                unsynced_step_ms > 0 ? 1000.0 / unsynced_step_ms : 0.0);
  t += buf;
  std::snprintf(buf, sizeof(buf), "| of which LPIPS fwd+bwd alone (separate run) | %.1f | |\n", lpips_ms);
  t += buf;
  return t;
}

std::string write_random_lpips_weights(const std::string& path, uint64_t seed) {
  auto gen = at::make_generator<at::CPUGeneratorImpl>(seed);
  TensorMap t;
  for (const auto& spec : loss::lpips_tensor_specs()) {
    auto x = at::randn(spec.shape, gen, at::kFloat);
    const int64_t fan_in = spec.shape.size() > 1 ? x.numel() / spec.shape[0] : 1;
    x = x * std::sqrt(2.0 / double(std::max<int64_t>(fan_in, 1)));
    if (spec.name.rfind("lin", 0) == 0) x = x.abs();
    t[spec.name] = x;
  }
  save_safetensors(path, t, {{"content", "random LPIPS weights for timing only"}});
  return path;
}

StepBenchmark benchmark_training(const TrainConfig& config, int64_t warmup, int64_t steps, bool profile) {
  FLAT_CHECK(!profile || config.device.rfind("cuda", 0) == 0,
             "flat_bench train: --profile needs device: cuda (GPU kernel times)");
  // The steady-state step: pruning at the config's full threshold from the
  // first timed step (a warm-up of the pruning would time unpruned renders).
  TrainConfig cfg = config;
  cfg.prune_warmup_steps = 0;
  torch::manual_seed(uint64_t(cfg.seed));
  TrainingSession session(cfg);
  data::LoaderConfig data_cfg = cfg.data;
  data_cfg.camera_rays = cfg.pipeline.model.camera_rays;
  data::Loader loader(data_cfg);
  StepBenchmark r;
  r.parameters_m = double(model::count_parameters(session.model())) / 1e6;
  std::vector<double> data, dec_f, ren_f, loss_f, rl_b, dec_b, opt, whole, unsynced;
  reset_peak_memory(session.device);
  for (int64_t i = 0; i < warmup + steps; ++i) {
    auto t0 = Clock::now();
    data::Batch batch = loader.next();
    const double data_ms = ms_since(t0);
    StepTimes times;
    auto out = session.step(batch, i, &times);
    sync(session.device);
    if (i < warmup) continue;
    data.push_back(data_ms);
    dec_f.push_back(times.decode_forward * 1e3);
    ren_f.push_back(times.render_forward * 1e3);
    loss_f.push_back(times.loss_forward * 1e3);
    rl_b.push_back(times.render_loss_backward * 1e3);
    dec_b.push_back(times.decoder_backward * 1e3);
    opt.push_back(out.optimiser_seconds * 1e3);
    whole.push_back(ms_since(t0));
    r.triangles = out.result.triangles;
  }
  // The same steps without phase synchronisation: the speed training runs at.
  for (int64_t i = 0; i < steps; ++i) {
    auto t0 = Clock::now();
    data::Batch batch = loader.next();
    session.step(batch, warmup + steps + i);
    sync(session.device);
    unsynced.push_back(ms_since(t0));
  }
  r.peak_gib = peak_memory_gib(session.device);
  if (profile) {
    data::Batch batch = loader.next();
    StepTimes times;
    const auto acts = record_gpu_activities([&] { session.step(batch, warmup + 2 * steps, &times); });
    print_step_profile(acts, times);
  }
  if (cfg.loss.lambda_perc > 0 && !session.vae_task()) {
    // LPIPS alone on images of the step's size and view count.
    const auto& d = cfg.data;
    auto a = torch::rand({d.target_views, 3, d.height, d.width}, torch::TensorOptions().device(session.device))
                 .requires_grad_(true);
    auto b = torch::rand({d.target_views, 3, d.height, d.width}, torch::TensorOptions().device(session.device));
    auto net = session.objective->lpips_network();
    std::vector<double> lp;
    for (int64_t i = 0; i < warmup + steps; ++i) {
      sync(session.device);
      auto t0 = Clock::now();
      {
        AutocastScope autocast(session.bf16, session.device.type());
        auto l = loss::lpips_distance(net, a, b, session.objective->lpips_options()).mean();
        l.backward();
      }
      sync(session.device);
      if (i >= warmup) lp.push_back(ms_since(t0));
    }
    r.lpips_ms = median(lp);
    if (profile) {
      const auto acts = record_gpu_activities([&] {
        AutocastScope autocast(session.bf16, session.device.type());
        loss::lpips_distance(net, a, b, session.objective->lpips_options()).mean().backward();
      });
      print_grouped("profile, LPIPS fwd+bwd alone, by class", acts, 12, kernel_class);
      print_grouped("profile, LPIPS fwd+bwd alone, by kernel", acts, 16,
                    [](const std::string& n) { return n.substr(0, 100); });
    }
  }
  r.steps = steps;
  r.data_ms = median(data);
  r.decode_forward_ms = median(dec_f);
  r.render_forward_ms = median(ren_f);
  r.loss_forward_ms = median(loss_f);
  r.render_loss_backward_ms = median(rl_b);
  r.decoder_backward_ms = median(dec_b);
  r.optimiser_ms = median(opt);
  r.step_ms = median(whole);
  r.unsynced_step_ms = median(unsynced);
  return r;
}

}  // namespace flat::bench
