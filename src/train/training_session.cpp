#include "flat/train/training_session.h"

#include <chrono>
#include <cmath>

#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/model/weights.h"
#include "flat/train/data_parallel.h"

namespace flat::train {

namespace {

double total_norm(const std::vector<at::Tensor>& grads) {
  if (grads.empty()) return 0;
  auto norms = at::_foreach_norm(grads, 2);
  return at::stack(norms).to(at::kDouble).norm().item<double>();
}

// init.from: checkpoint: the model weights of an earlier stage (run folder,
// checkpoint folder or model file), checked against this stage's signature.
void load_earlier_stage(torch::nn::Module& model, const std::string& path, const ModelSignature& signature) {
  const std::string file = resolve_model_file(path);
  Metadata meta;
  auto tensors = load_safetensors(file, &meta);
  load_model_weights(model, tensors, {meta.count("model_signature") ? meta["model_signature"] : "", ""}, signature,
                     file);
  spdlog::info("init: model weights of the earlier stage from {}", file);
}

}  // namespace

TrainingSession::TrainingSession(const TrainConfig& cfg)
    : TrainingSession(cfg, at::Device(cfg.device == "cuda" ? at::kCUDA : at::kCPU)) {}

ModelSignature vae_signature(const model::WanVAEConfig& config) {
  config::Describer d("vae.");
  auto c = config;
  c.visit(d);
  std::string yaml = "task: vae\n";
  for (const auto& row : d.rows) yaml += row.key + ": " + row.value + "\n";
  return {yaml, ""};
}

torch::nn::Module& TrainingSession::model() {
  if (vae_task()) return *vae;
  return *decoder;
}

TrainingSession::TrainingSession(const TrainConfig& cfg, const at::Device& on) : grad_clip_(cfg.optim.grad_clip) {
  device = on;
  if (device.is_cuda() && !torch::cuda::is_available())
    fail("device: cuda requested but no CUDA device is available (set device: cpu)");
  if (device.is_cuda() && device.has_index() && device.index() >= torch::cuda::device_count())
    fail("device: " + device.str() + " requested but only " + std::to_string(torch::cuda::device_count()) +
         " CUDA device(s) are visible");
  bf16 = cfg.precision == "bf16" && device.is_cuda();
  if (device.is_cuda()) at::globalContext().setBenchmarkCuDNN(cfg.cudnn_benchmark);
  // Field by field: a positional list would swap values silently when a field moves.
  schedule.peak = cfg.optim.lr;
  schedule.warmup_steps = cfg.optim.warmup_steps;
  schedule.total_steps = cfg.steps;
  schedule.shape = cfg.optim.schedule;
  schedule.min_ratio = cfg.optim.min_lr_ratio;
  optim::AdamWOptions adamw;
  adamw.beta1 = cfg.optim.beta1;
  adamw.beta2 = cfg.optim.beta2;
  adamw.eps = cfg.optim.eps;
  adamw.weight_decay = cfg.optim.weight_decay;
  adamw.fused = cfg.optim.fused;
  adamw.fused_8bit = cfg.optim.fused_8bit;
  adamw.state_bits = cfg.optim.name == "adamw8bit" ? 8 : 32;
  if (cfg.task == "vae") {
    vae = model::WanVAE(cfg.pipeline.model.vae, cfg.pipeline.model.kernels);
    vae_loss = cfg.vae;
    signature = vae_signature(cfg.pipeline.model.vae);
    if (cfg.init.from == "wan_vae") {
      auto report = model::load_weights(*vae, cfg.init.path);
      spdlog::info("init: the whole VAE from {}", report.summary());
    } else if (cfg.init.from == "checkpoint") {
      load_earlier_stage(*vae, cfg.init.path, signature);
    }
    if (cfg.init.from == "scratch") initialise_vae_for_training(vae);
    vae->to(device);
    if (cfg.vae.lpips > 0) {
      vae_lpips = loss::Lpips();
      vae_lpips->load(cfg.loss.lpips_weights);
      vae_lpips->to(device);
      vae_lpips->eval();
      for (auto& p : vae_lpips->parameters()) p.requires_grad_(false);
    }
    optimiser = std::make_unique<optim::AdamW>(vae->named_parameters().pairs(), adamw);
    return;
  }
  decoder = model::SceneDecoder(cfg.pipeline.model, cfg.pipeline.channels());
  signature = pipeline::model_signature(cfg.pipeline);
  if (cfg.init.from == "wan_vae") {
    auto report = decoder->load_pretrained_vae(cfg.init.path);
    spdlog::info("init: {}", report.summary());
  } else if (cfg.init.from == "checkpoint") {
    load_earlier_stage(*decoder, cfg.init.path, signature);
  }
  decoder->to(device);
  pipeline = std::make_unique<pipeline::ScenePipeline>(cfg.pipeline, decoder);
  objective = std::make_unique<loss::Objective>(cfg.loss, device, bf16);
  if (cfg.loss.random_background) background_seed_ = int64_t(cfg.seed);
  prune_opacity_ = cfg.pipeline.prune_opacity;
  prune_warmup_steps_ = cfg.prune_warmup_steps;
  optimiser = std::make_unique<optim::AdamW>(decoder->named_parameters().pairs(), adamw);
}

void TrainingSession::set_opacity_shift(double shift) {
  FLAT_CHECK(pipeline, "set_opacity_shift: the VAE stage has no pipeline");
  pipeline->set_opacity_shift(shift);
  signature = model_signature(pipeline->config());
}

void TrainingSession::use_data_parallel(DataParallel* dp) {
  dp_ = dp;
  if (!dp_) return;
  std::vector<at::Tensor> params;
  for (const auto& p : model().parameters())
    if (p.requires_grad()) params.push_back(p);
  dp_->reduce_gradients_of(params);
}

StepOutcome TrainingSession::step(const data::Batch& batch, int64_t step, StepTimes* times, int stop_signal) {
  StepOutcome out;
  optimiser->zero_grad();
  if (dp_) dp_->before_backward();
  out.result = vae_task() ? vae_forward_backward(vae, vae_loss, vae_lpips, batch, bf16, times)
                          : forward_backward(*pipeline, *objective, batch, bf16, times,
                                             background_seed_ < 0 ? -1 : background_seed_ * 1000003 + step,
                                             training_prune_opacity(prune_opacity_, prune_warmup_steps_, step));
  out.stop_signal = stop_signal;
  if (dp_) {
    // Every rank comes here, also one whose loss was not finite (no backward):
    // it sends no gradient, and all ranks skip the step together.
    dp_->after_backward();
    out.stop_signal = dp_->agree(out.result, stop_signal);
  }
  const auto t0 = std::chrono::steady_clock::now();
  out.lr = schedule.at(step);
  bool ok = out.result.finite;
  if (ok) {
    auto grads = optimiser->grads();
    out.grad_norm = total_norm(grads);
    ok = std::isfinite(out.grad_norm);
    if (ok && grad_clip_ > 0 && out.grad_norm > grad_clip_) at::_foreach_mul_(grads, grad_clip_ / (out.grad_norm + 1e-6));
  }
  if (ok) {
    optimiser->step(out.lr);
  } else {
    optimiser->zero_grad();
  }
  out.applied = ok;
  if (times && device.is_cuda()) torch::cuda::synchronize();
  out.optimiser_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

}  // namespace flat::train
