#include "flat/train/train_config.h"

#include "flat/core/error.h"

namespace flat::train {

void InitConfig::check() const {
  if (from != "scratch" && path.empty()) fail("'path' is required with from: " + from);
  if (from == "scratch" && !path.empty()) fail("'path' is set but from is scratch (set from: checkpoint or wan_vae)");
}

void TrainConfig::check() const {
  if (run_dir.empty()) fail("'run_dir' is empty");
  if (pipeline.model.vae.z_dim != 16)
    fail("'pipeline.model.vae.z_dim' must be 16 (the Wan 2.1 latent the data tools store)");
  if (task == "vae") {
    if (!data.input_images) fail("task: vae trains on the frames: set 'data.input_images: true'");
    if (data.latents) fail("task: vae encodes the frames itself: set 'data.latents: false'");
    if (vae.lpips > 0 && loss.lpips_weights.empty())
      fail("'vae.lpips' > 0 needs 'loss.lpips_weights' (see docs/losses.md), or set vae.lpips: 0");
    if (vae.l1 + vae.l2 + vae.lpips <= 0) fail("task: vae needs a reconstruction loss: 'vae.l1', 'vae.l2' or 'vae.lpips' > 0");
    if (data.height % 8 != 0 || data.width % 8 != 0)
      fail("task: vae: 'data.height' and 'data.width' must be multiples of 8 (the VAE downsamples by 8), got " +
           std::to_string(data.height) + "x" + std::to_string(data.width));
  } else {
    if (loss.lambda_perc > 0 && loss.lpips_weights.empty())
      fail("'loss.lambda_perc' > 0 needs 'loss.lpips_weights' (see docs/losses.md), or set lambda_perc: 0");
    if (!data.latents) fail("'data.latents' must be true: the scene decoder trains on precomputed latents");
  }
  if (optim.warmup_steps > steps)
    fail("'optim.warmup_steps' (" + std::to_string(optim.warmup_steps) + ") exceeds 'steps' (" +
         std::to_string(steps) + ")");
}

std::string describe_config() {
  TrainConfig defaults;
  config::Describer d;
  defaults.visit(d);
  return d.markdown();
}

}  // namespace flat::train
