#include "flat/train/vae_stage.h"

#include <chrono>
#include <cmath>

#include <torch/torch.h>

#include "flat/core/autocast_scope.h"
#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/eval/baselines.h"
#include "flat/eval/image_metrics.h"
#include "flat/eval/latent_spread.h"
#include "flat/model/weights.h"

namespace flat::train {

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

void sync_if_timing(StepTimes* times, const at::Device& device) {
  if (times && device.is_cuda()) torch::cuda::synchronize(device.index() < 0 ? 0 : device.index());
}

// (B,3,F,H,W) in [-1,1] -> (B*F,3,H,W) in [0,1].
at::Tensor as_frames(const at::Tensor& video) {
  return ((video.permute({0, 2, 1, 3, 4}).flatten(0, 1) + 1) * 0.5);
}

}  // namespace

void initialise_vae_for_training(model::WanVAE& vae) {
  torch::NoGradGuard no_grad;
  auto ends_with = [](const std::string& s, const std::string& tail) {
    return s.size() >= tail.size() && s.compare(s.size() - tail.size(), tail.size(), tail) == 0;
  };
  for (auto& item : vae->named_parameters()) {
    const std::string& name = item.key();
    at::Tensor p = item.value();
    if (ends_with(name, ".bias")) {
      p.zero_();
    } else if (ends_with(name, ".weight") && p.dim() >= 2) {
      if (ends_with(name, "residual.6.weight") || ends_with(name, "proj.weight")) {
        p.zero_();  // the residual branch starts at zero: the block is the identity
      } else if (ends_with(name, "time_conv.weight")) {
        // Temporal resampling starts as "the newest frame" (its last causal
        // tap), for each output half of an upsample (C -> 2C: the frame
        // repeated): a VAE trained on single frames, which never runs these,
        // then decodes a still video as repeated frames instead of noise.
        p.zero_();
        const int64_t c = p.size(1), taps = p.size(2);
        for (int64_t o = 0; o < p.size(0); ++o) p[o][o % c][taps - 1].fill_(1.0);
      } else {
        const double fan_in = double(p[0].numel());
        p.normal_(0.0, 1.0 / std::sqrt(fan_in));
      }
    }
  }
  const int64_t z = vae->config().z_dim;
  vae->conv1->weight.narrow(0, z, z).zero_();
  vae->conv1->bias.narrow(0, z, z).fill_(-10.0);
}

at::Tensor vae_video(const data::Batch& batch, const at::Device& device) {
  FLAT_CHECK(batch.input_images.defined(), "VAE stage: the batch has no input frames (data.input_images: true)");
  check_shape(batch.input_images, {-1, -1, 3, -1, -1}, "VAE stage: input frames", "(B,F,3,H,W)");
  return batch.input_images.to(device, at::kFloat).permute({0, 2, 1, 3, 4}).mul(2).sub(1).contiguous();
}

StepResult vae_forward_backward(model::WanVAE& vae, const VaeStageConfig& cfg, loss::Lpips lpips,
                                const data::Batch& batch, bool bf16, StepTimes* times) {
  const auto device = vae->conv2->weight.device();
  StepResult r;
  auto t0 = Clock::now();
  const at::Tensor video = vae_video(batch, device);
  const int64_t z = vae->config().z_dim;
  at::Tensor total;
  {
    AutocastScope autocast(bf16 && device.is_cuda(), device.type());
    auto moments = vae->encode_moments(video, /*streaming=*/false).to(at::kFloat);
    auto mu = moments.narrow(1, 0, z);
    auto log_var = moments.narrow(1, z, z).clamp(-30.0, 20.0);
    auto sample = mu + at::exp(0.5 * log_var) * at::randn_like(mu);
    auto recon = vae->decoder->forward(vae->conv2->forward(sample)).to(at::kFloat);
    sync_if_timing(times, device);
    if (times) times->decode_forward += seconds_since(t0);
    t0 = Clock::now();

    auto diff = recon - video;
    auto l1 = diff.abs().mean();
    auto l2 = diff.square().mean();
    auto kl = 0.5 * (mu.square() + log_var.exp() - 1.0 - log_var).mean();
    total = cfg.l1 * l1 + cfg.l2 * l2 + cfg.kl * kl;
    std::vector<std::pair<std::string, at::Tensor>> terms = {{"l1", l1}, {"l2", l2}, {"kl", kl}};
    if (cfg.lpips > 0) {
      FLAT_CHECK(!lpips.is_empty(), "VAE stage: vae.lpips > 0 but no LPIPS network was loaded");
      auto lp = loss::lpips_distance(lpips, as_frames(recon).clamp(0, 1), as_frames(video),
                                     {.max_size = 512, .chunk = 8, .checkpoint = true, .bf16 = bf16 && device.is_cuda()})
                    .mean();
      total = total + cfg.lpips * lp;
      terms.push_back({"lpips", lp});
    }
    terms.push_back({"total", total});
    // "rgb": mean squared error of the frames in [0,1], as the scene stage's rgb term.
    terms.push_back({"rgb", l2 * 0.25});
    std::vector<at::Tensor> values;
    for (const auto& t : terms) values.push_back(t.second.detach().reshape({}).to(at::kDouble));
    const auto host = at::stack(values).cpu();
    for (size_t i = 0; i < terms.size(); ++i) r.terms[terms[i].first] = host[int64_t(i)].item<double>();
  }
  r.loss = r.terms["total"];
  sync_if_timing(times, device);
  if (times) times->loss_forward += seconds_since(t0);
  if (!std::isfinite(r.loss)) {
    r.finite = false;
    std::string bad;
    for (const auto& [name, value] : r.terms)
      if (!std::isfinite(value)) bad += " " + name;
    r.nonfinite = "VAE loss terms:" + bad;
    return r;
  }
  t0 = Clock::now();
  total.backward();
  sync_if_timing(times, device);
  if (times) times->decoder_backward += seconds_since(t0);
  return r;
}

ValidationResult validate_vae(model::WanVAE& vae, data::Loader& loader, int64_t samples, loss::Lpips lpips,
                              int64_t grid_views, distributed::ProcessGroup* group) {
  torch::NoGradGuard no_grad;
  const bool was_training = vae->is_training();
  vae->eval();
  ValidationResult r;
  double psnr = 0, ssim = 0, lp = 0, base = 0;
  const auto device = vae->conv2->weight.device();
  const int64_t first = group ? group->rank() : 0, stride = group ? group->world_size() : 1;
  std::vector<at::Tensor> latents;
  int64_t grid_rows = 0;
  for (int64_t i = first; i < samples; i += stride) {
    data::Batch batch = loader.batch(i);
    const at::Tensor video = vae_video(batch, device);
    auto mu = vae->encode_moments(video, /*streaming=*/false).narrow(1, 0, vae->config().z_dim);
    auto recon = vae->decoder->forward(vae->conv2->forward(mu)).clamp(-1, 1);
    for (int64_t b = 0; b < video.size(0); ++b) {
      auto target = as_frames(video.narrow(0, b, 1));
      auto rgb = as_frames(recon.narrow(0, b, 1));
      psnr += eval::psnr(rgb, target).sum().item<double>();
      ssim += eval::ssim(rgb, target).sum().item<double>();
      if (!lpips.is_empty()) lp += eval::lpips(lpips, rgb, target, 512, 4).sum().item<double>();
      base += eval::mean_colour_psnr(target).sum().item<double>();
      r.views += target.size(0);
      latents.push_back(mu[b].cpu());
      // Grid rows: the last frame of each of this rank's first windows (input | reconstruction).
      if (grid_rows < grid_views) {
        const int64_t last = target.size(0) - 1;
        std::vector<at::Tensor> tiles;
        for (const auto& c : {target, rgb})
          tiles.push_back(at::constant_pad_nd(c[last].to(at::kCPU, at::kFloat), {0, 2, 0, 2}, 1.0));
        auto row = at::cat(tiles, 2);
        r.grid = r.grid.defined() ? at::cat({r.grid, row}, 1).contiguous() : row.contiguous();
        ++grid_rows;
      }
    }
    r.samples += video.size(0);
  }
  // The spread of the latents: over this rank's samples (all of them in one process).
  const auto spread = eval::latent_spread(latents);
  double corr_sum = std::isnan(spread.mean_correlation) ? 0 : spread.mean_correlation * double(spread.pairs);
  double pairs = double(spread.pairs);
  if (group) {
    auto sums = distributed::sum_over_ranks(
        *group, {psnr, ssim, lp, base, double(r.views), double(r.samples), corr_sum, pairs}, device);
    psnr = sums[0], ssim = sums[1], lp = sums[2], base = sums[3];
    r.views = int64_t(std::llround(sums[4]));
    r.samples = int64_t(std::llround(sums[5]));
    corr_sum = sums[6], pairs = sums[7];
  }
  const double v = double(std::max<int64_t>(r.views, 1));
  r.psnr = psnr / v;
  r.ssim = ssim / v;
  r.lpips = lpips.is_empty() ? NAN : lp / v;
  r.mean_colour_psnr = base / v;
  r.latent_correlation = pairs > 0 ? corr_sum / pairs : NAN;
  if (was_training) vae->train();
  return r;
}

LatentStatistics measure_latent_statistics(model::WanVAE& vae, data::Loader& loader, int64_t samples) {
  torch::NoGradGuard no_grad;
  const bool was_training = vae->is_training();
  vae->eval();
  const auto device = vae->conv2->weight.device();
  const int64_t z = vae->config().z_dim;
  auto sum = at::zeros({z}, at::kDouble), sum_sq = at::zeros({z}, at::kDouble);
  double count = 0;
  LatentStatistics s;
  for (int64_t i = 0; s.samples < samples; ++i) {
    data::Batch batch = loader.batch(i);
    auto mu = vae->encode_moments(vae_video(batch, device), /*streaming=*/false).narrow(1, 0, z);
    auto x = mu.to(at::kCPU, at::kDouble).transpose(0, 1).reshape({z, -1});
    sum += x.sum(1);
    sum_sq += x.square().sum(1);
    count += double(x.size(1));
    s.samples += mu.size(0);
  }
  s.mean = sum / count;
  s.std = (sum_sq / count - s.mean.square()).clamp_min(1e-12).sqrt();
  if (was_training) vae->train();
  return s;
}

void write_vae_file(const model::WanVAE& vae, const LatentStatistics& stats, const std::string& path,
                    Metadata metadata) {
  model::WanVAE copy(vae->config());
  model::load_state(*copy, model::state_tensors(*vae), {}, "the trained VAE");
  copy->fold_latent_statistics(stats.mean, stats.std);
  auto list = [](const at::Tensor& t) {
    std::string out = "[";
    for (int64_t i = 0; i < t.numel(); ++i) out += (i ? ", " : "") + std::to_string(t[i].item<double>());
    return out + "]";
  };
  metadata["latent_mean"] = list(stats.mean);
  metadata["latent_std"] = list(stats.std);
  metadata["latent_statistics"] = "measured on " + std::to_string(stats.samples) +
                                  " training windows and folded into conv1/conv2: normalising with Wan 2.1's "
                                  "constants gives zero mean and unit spread per channel";
  metadata["vae_dim"] = std::to_string(vae->config().dim);
  model::save_weights(*copy, path, model::WeightNaming::wan, metadata);
}

}  // namespace flat::train
