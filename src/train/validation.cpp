#include "flat/train/validation.h"

#include <cmath>
#include <map>
#include <utility>

#include <torch/torch.h>

#include "flat/core/autocast_scope.h"
#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/shape.h"
#include "flat/core/tensor_io.h"
#include "flat/eval/baselines.h"
#include "flat/eval/image_metrics.h"
#include "flat/eval/normal_metrics.h"

namespace flat::train {

namespace {

// (V,1,H,W) depth -> (V,3,H,W) grey in [0,1]: near bright, far dark, over
// [lo, hi]; no depth (0) is black.
at::Tensor depth_image(const at::Tensor& depth, double lo, double hi) {
  auto d = ((hi - depth) / std::max(hi - lo, 1e-6)).clamp(0, 1);
  d = at::where(depth > 0, d, at::zeros_like(d));
  return d.expand({-1, 3, -1, -1});
}

at::Tensor normal_image(const at::Tensor& n) { return (n * 0.5 + 0.5).clamp(0, 1); }

}  // namespace

Scalars ValidationResult::scalars() const {
  Scalars out = {{"val_psnr", psnr},
                 {"val_ssim", ssim},
                 {"val_lpips", lpips},
                 {"val_normal_cosine", normal_cosine},
                 {"val_mean_colour_psnr", mean_colour_psnr}};
  // The baselines that apply to the stage (NaN: not measured here).
  for (const auto& [name, value] : Scalars{{"val_dataset_mean_psnr", dataset_mean_psnr},
                                           {"val_swap_psnr", swap_psnr},
                                           {"val_latent_correlation", latent_correlation}})
    if (!std::isnan(value)) out.push_back({name, value});
  return out;
}

at::Tensor training_mean_image(const data::LoaderConfig& config, int64_t samples) {
  data::LoaderConfig c = config;
  c.batch_size = 1;
  c.workers = 0;
  c.depth = false;
  c.normals = false;
  c.input_images = false;
  c.latents = false;
  data::Loader loader(c);
  at::Tensor sum;
  int64_t n = 0;
  for (int64_t i = 0; i < samples; ++i) {
    auto t = loader.batch(i).target_images[0].to(at::kDouble);  // (V,3,H,W)
    sum = sum.defined() ? sum + t.sum(0) : t.sum(0);
    n += t.size(0);
  }
  return (sum / double(std::max<int64_t>(n, 1))).to(at::kFloat);
}

at::Tensor validation_grid(const pipeline::RenderedViews& views, const data::Batch& batch, int64_t b,
                           int64_t max_views) {
  const int64_t V = std::min<int64_t>(max_views, views.rgb.size(0));
  auto gt = batch.target_images[b].slice(0, 0, V).to(at::kFloat);
  auto rgb = views.rgb.detach().slice(0, 0, V).cpu().clamp(0, 1);
  const auto H = gt.size(2), W = gt.size(3);
  auto ref_depth = batch.target_depth.defined() ? batch.target_depth[b].slice(0, 0, V).to(at::kFloat)
                                                : at::zeros({V, 1, H, W});
  auto valid = ref_depth.gt(0);
  double lo = 0, hi = 1;
  if (valid.any().item<bool>()) {
    lo = ref_depth.masked_select(valid).min().item<double>();
    hi = ref_depth.masked_select(valid).max().item<double>();
  }
  auto ref_normals = batch.target_normals.defined() ? batch.target_normals[b].slice(0, 0, V).to(at::kFloat)
                                                    : at::zeros({V, 3, H, W});
  // The disparity loss is scale- and shift-invariant, so a render's depth is
  // shown over its own range (pixels with alpha > 0.5), not the reference's.
  auto rd = views.depth.detach().slice(0, 0, V).cpu();
  auto covered = views.alpha.detach().slice(0, 0, V).cpu().gt(0.5) & rd.gt(0);
  double rlo = lo, rhi = hi;
  if (covered.any().item<bool>()) {
    rlo = rd.masked_select(covered).min().item<double>();
    rhi = rd.masked_select(covered).max().item<double>();
  }
  auto cols = {gt,
               rgb,
               depth_image(rd, rlo, rhi),
               depth_image(ref_depth, lo, hi),
               normal_image(views.normal.detach().slice(0, 0, V).cpu()),
               at::where(ref_normals.norm(2, 1, true) > 0.5, normal_image(ref_normals), at::zeros_like(ref_normals))};
  // A 2-pixel white gap between tiles.
  std::vector<at::Tensor> rows;
  for (int64_t v = 0; v < V; ++v) {
    std::vector<at::Tensor> tiles;
    for (const auto& c : cols) {
      tiles.push_back(at::constant_pad_nd(c[v], {0, 2, 0, 2}, 1.0));
    }
    rows.push_back(at::cat(tiles, 2));
  }
  return at::cat(rows, 1).contiguous();
}

ValidationResult validate(pipeline::ScenePipeline& pipeline, data::Loader& loader, int64_t samples,
                          loss::Lpips lpips, int64_t grid_views, distributed::ProcessGroup* group,
                          const at::Tensor& dataset_mean, bool bf16) {
  torch::NoGradGuard no_grad;
  ValidationResult r;
  double psnr = 0, ssim = 0, lp = 0, base = 0, cosine = 0, mean_image = 0, swap = 0, swap_views = 0;
  int64_t grid_rows = 0;
  int64_t normal_pixels = 0;
  const auto device = pipeline.decoder()->conv2->weight.device();
  const int64_t first = group ? group->rank() : 0, stride = group ? group->world_size() : 1;
  const bool autocast_on = bf16 && device.is_cuda();
  // Each sample's scene and target images, loaded once whether it is scored
  // here or only a swap partner.
  std::map<int64_t, std::pair<std::string, at::Tensor>> held_out;
  auto targets_of = [&](int64_t index) -> const std::pair<std::string, at::Tensor>& {
    auto it = held_out.find(index);
    if (it == held_out.end()) {
      data::Batch other = loader.batch(index);
      it = held_out.emplace(index, std::make_pair(other.scenes[0], other.target_images[0])).first;
    }
    return it->second;
  };
  for (int64_t i = first; i < samples; i += stride) {
    data::Batch batch = loader.batch(i);
    held_out.emplace(i, std::make_pair(batch.scenes[0], batch.target_images[0]));
    pipeline::SceneInput in{batch.video_latents, batch.camera_latents, batch.input_intrinsics, batch.input_c2w};
    // Decode and render under the run's precision; the scores in fp32.
    auto soup = [&] {
      AutocastScope autocast(autocast_on, device.type());
      return pipeline.decode(in);
    }();
    for (int64_t b = 0; b < soup.batch(); ++b) {
      const int64_t H = batch.target_images.size(3), W = batch.target_images.size(4);
      auto views = [&] {
        AutocastScope autocast(autocast_on, device.type());
        return pipeline.render(soup.scene(b), batch.target_cameras(b).to(device), H, W);
      }();
      for (auto* t : {&views.rgb, &views.alpha, &views.depth, &views.normal})
        if (t->defined()) *t = t->to(at::kFloat);
      auto target = batch.target_images[b].to(device, at::kFloat);
      auto rgb = views.rgb.clamp(0, 1);
      psnr += eval::psnr(rgb, target).sum().item<double>();
      ssim += eval::ssim(rgb, target).sum().item<double>();
      if (!lpips.is_empty()) lp += eval::lpips(lpips, rgb, target, 512, 4).sum().item<double>();
      base += eval::mean_colour_psnr(target).sum().item<double>();
      if (dataset_mean.defined())
        mean_image += eval::psnr(dataset_mean.to(device).unsqueeze(0).expand_as(target), target).sum().item<double>();
      // Swap: the same renders against the views of the next sample of
      // another scene (same view index); samples are drawn with replacement,
      // and a sample of the same scene is no swap.
      at::Tensor partner;
      for (int64_t k = 1; k < samples && !partner.defined(); ++k) {
        const auto& candidate = targets_of((i + k) % samples);
        if (candidate.first != batch.scenes[b]) partner = candidate.second;
      }
      if (partner.defined()) {
        auto other = partner.to(device, at::kFloat);
        FLAT_CHECK(other.sizes() == target.sizes(), "validation: the swap baseline needs samples of the same views "
                                                    "and size, got " + shape_str(other) + " and " + shape_str(target));
        swap += eval::psnr(rgb, other).sum().item<double>();
        swap_views += double(target.size(0));
      }
      if (batch.target_normals.defined() && batch.normals_present[b].item<bool>()) {
        auto acc = eval::normal_accuracy(views.normal, batch.target_normals[b].to(device, at::kFloat),
                                         views.alpha > 0.5);
        if (acc.valid_pixels > 0) {
          cosine += acc.mean_cosine * double(acc.valid_pixels);
          normal_pixels += acc.valid_pixels;
        }
      }
      r.views += target.size(0);
      // Grid rows: the first view of each of this rank's first samples, so
      // that a reader sees whether each held-out scene gets its own layout.
      if (grid_rows < grid_views) {
        auto row = validation_grid(views, batch, b, 1);
        r.grid = r.grid.defined() ? at::cat({r.grid, row}, 1) : row;
        ++grid_rows;
      }
    }
    r.samples += soup.batch();
  }
  if (group) {
    auto sums = distributed::sum_over_ranks(
        *group,
        {psnr, ssim, lp, base, cosine, double(normal_pixels), double(r.views), double(r.samples), mean_image, swap,
         swap_views},
        device);
    psnr = sums[0], ssim = sums[1], lp = sums[2], base = sums[3], cosine = sums[4];
    mean_image = sums[8], swap = sums[9], swap_views = sums[10];
    normal_pixels = int64_t(std::llround(sums[5]));
    r.views = int64_t(std::llround(sums[6]));
    r.samples = int64_t(std::llround(sums[7]));
  }
  const double v = double(std::max<int64_t>(r.views, 1));
  r.psnr = psnr / v;
  r.ssim = ssim / v;
  r.lpips = lpips.is_empty() ? NAN : lp / v;
  r.mean_colour_psnr = base / v;
  r.dataset_mean_psnr = dataset_mean.defined() ? mean_image / v : NAN;
  r.swap_psnr = swap_views > 0 ? swap / swap_views : NAN;
  r.normal_cosine = normal_pixels > 0 ? cosine / double(normal_pixels) : NAN;
  return r;
}

}  // namespace flat::train
