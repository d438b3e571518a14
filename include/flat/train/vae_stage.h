// The VAE stage (task: vae; train_config.h, VaeStageConfig): the Wan 2.1 VAE
// trained as a video autoencoder on scene frames, by the same trainer as the
// scene decoder (run folder, checkpoints and exact resume, metrics,
// validation, data parallelism). Its output, <run>/vae.safetensors, is a VAE
// file in Wan's original key names with the latent statistics folded in
// (WanVAE::fold_latent_statistics): flat_vae, flat_latents --vae and
// flat_train's init.from: wan_vae read it as they read the real Wan weights.
//
//   frames (B,F,3,H,W) in [0,1] -> x = 2 frames - 1 (B,3,F,H,W)
//   -> encoder, conv1 -> (mu, log_var) -> z = mu + exp(log_var / 2) eps
//   -> conv2, decoder -> x^;  loss = l1 |x^-x| + l2 (x^-x)^2 + lpips + kl KL
#pragma once
#include <cstdint>
#include <string>

#include <ATen/ATen.h>

#include "flat/core/tensor_io.h"
#include "flat/data/loader.h"
#include "flat/distributed/process_group.h"
#include "flat/loss/lpips.h"
#include "flat/model/wan_vae.h"
#include "flat/train/train_config.h"
#include "flat/train/train_step.h"
#include "flat/train/validation.h"

namespace flat::train {

// The VAE stage's initialisation from scratch (init.from: scratch). With
// PyTorch's default conv init (variance 1/(3 fan_in)) a deep random Wan
// encoder shrinks its input at every conv until the biases dominate: every
// video maps to nearly the same latent (correlation ~0.99 across scenes),
// and training from there stalls at the average frame. So: convolutions
// variance-preserving (normal, std 1/sqrt(fan_in)), biases zero, the last conv
// of every residual block and attention output zero (blocks start as the
// identity), and the posterior nearly deterministic (log-variance -10: its
// noise would otherwise drown the young encoder's mu). Seeded like any init.
void initialise_vae_for_training(model::WanVAE& vae);

// The batch's input frames as the VAE's video: (B,3,F,H,W) in [-1,1].
at::Tensor vae_video(const data::Batch& batch, const at::Device& device);

// Forward and backward of one batch (gradients accumulate into vae's
// parameters). Terms: "l1", "l2", "lpips", "kl" (unweighted) and "total";
// "rgb" is the mean squared error of the frames in [0,1] (the progress line's
// column, comparable with the scene stage's).
StepResult vae_forward_backward(model::WanVAE& vae, const VaeStageConfig& cfg, loss::Lpips lpips,
                                const data::Batch& batch, bool bf16, StepTimes* times = nullptr);

// Reconstructs the input windows of samples 0..samples-1 from their mean
// latent (no sampling) and scores every frame: PSNR, SSIM, LPIPS, the
// mean-colour baseline, and the spread of the latents across samples
// (eval/latent_spread.h). Grid: the last frame of each of the first
// `grid_views` windows, input | reconstruction.
ValidationResult validate_vae(model::WanVAE& vae, data::Loader& loader, int64_t samples, loss::Lpips lpips,
                              int64_t grid_views, distributed::ProcessGroup* group = nullptr);

// Per-channel mean and standard deviation of the raw mu over `samples`
// batches of `loader` ((16,) each, float64 on the CPU).
struct LatentStatistics {
  at::Tensor mean, std;
  int64_t samples = 0;
};
LatentStatistics measure_latent_statistics(model::WanVAE& vae, data::Loader& loader, int64_t samples);

// Writes a copy of `vae` with `stats` folded in to `path` (Wan naming,
// atomic), the raw statistics in the metadata ("latent_mean", "latent_std").
void write_vae_file(const model::WanVAE& vae, const LatentStatistics& stats, const std::string& path,
                    Metadata metadata);

}  // namespace flat::train
