#include "flat/train/validation.h"

#include <algorithm>
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
#include "flat/eval/scene_evaluation.h"
#include "flat/data/frame_resize.h"
#include "flat/data/scene_frames.h"
#include "flat/data/scene_latents.h"

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
                 {"val_normal_l1", normal_l1},
                 {"val_mean_colour_psnr", mean_colour_psnr}};
  // The baselines that apply to the stage (NaN: not measured here).
  for (const auto& [name, value] : Scalars{{"val_depth_si_log", depth_si_log},
                                           {"val_planar_roughness", planar_roughness},
                                           {"val_dataset_mean_psnr", dataset_mean_psnr},
                                           {"val_swap_psnr", swap_psnr},
                                           {"val_latent_correlation", latent_correlation}})
    if (!std::isnan(value)) out.push_back({name, value});
  return out;
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

HeldOut held_out_scenes(const std::vector<data::DatasetSource>& datasets, int64_t count, int64_t height,
                        int64_t width, int64_t frames) {
  HeldOut h;
  for (size_t k = 0; k < datasets.size(); ++k) {
    const auto& d = datasets[k];
    if (!(d.weight > 0)) continue;
    for (const auto& dir : data::scene_dirs_under(d.root)) {
      if (count > 0 && int64_t(h.scenes.size()) >= count) return h;
      data::Scene scene = data::read_scene(dir);
      // Only scenes holding the stage's set are held out (the validation
      // loader has reported the others, per dataset).
      if (!data::find_latent_set(scene, height, width, frames)) continue;
      data::select_latent_set(scene, height, width, frames);
      h.scenes.push_back(std::move(scene));
      h.dataset.push_back(k);
    }
  }
  FLAT_CHECK(!h.scenes.empty(), "validation: no held-out scene holds the latent set " +
                                    data::latent_set_key(height, width, frames) + " of this stage");
  return h;
}

eval::EvalSettings validation_settings(int64_t max_views, bool bf16) {
  eval::EvalSettings s;  // flat_eval's defaults: every view of the scene, window 0, skimage SSIM
  s.max_views = max_views;
  s.bf16 = bf16;
  return s;
}

void HeldOut::measure_frames(const eval::EvalSettings& settings) {
  frame_sums.clear();
  for (size_t i = 0; i < scenes.size(); ++i) eval::add_frame_sums(frame_sums[dataset[i]], scenes[i], settings);
}

std::optional<size_t> HeldOut::swap_partner(size_t i) const {
  std::vector<size_t> same;  // the scenes of i's dataset, in order
  for (size_t j = 0; j < scenes.size(); ++j)
    if (dataset[j] == dataset[i]) same.push_back(j);
  const size_t at = size_t(std::find(same.begin(), same.end(), i) - same.begin());
  const auto p = eval::swap_partner(at, same.size());
  return p ? std::optional<size_t>(same[*p]) : std::nullopt;
}

namespace {

// One grid row: the scene's first evaluation view, decoded from window 0.
at::Tensor validation_grid_row(pipeline::ScenePipeline& pipeline, const data::Scene& scene,
                               const eval::EvalSettings& s) {
  const auto device = pipeline.decoder()->conv2->weight.device();
  const auto in = eval::window_input(scene, s.window, pipeline.config().model.camera_rays);
  const int64_t view = eval::evaluation_views(scene, s).front();
  const int64_t H = scene.latents.height, W = scene.latents.width;
  auto frames = data::load_frames(scene, {view}, scene.has_depth, scene.has_normals);
  auto intr = data::fit_frames(frames, scene.cameras({view}).intrinsics, H, W);
  pipeline::RenderedViews v;
  {
    AutocastScope autocast(s.bf16 && device.is_cuda(), device.type());
    auto soup = pipeline.decode(in, s.streaming);
    v = pipeline.render(soup.scene(0), camera::Cameras{intr.to(device), scene.cameras({view}).c2w.to(device)}, H, W);
  }
  for (auto* t : {&v.rgb, &v.alpha, &v.depth, &v.normal})
    if (t->defined()) *t = t->to(at::kCPU, at::kFloat);
  data::Batch b;
  b.target_images = frames.images.unsqueeze(0);
  if (frames.depth.defined()) b.target_depth = frames.depth.unsqueeze(0);
  if (frames.normals.defined()) b.target_normals = frames.normals.unsqueeze(0);
  return validation_grid(v, b, 0, 1);
}

}  // namespace

ValidationResult validate(pipeline::ScenePipeline& pipeline, const HeldOut& held_out,
                          const eval::EvalSettings& settings, loss::Lpips lpips, int64_t grid_views,
                          distributed::ProcessGroup* group) {
  const auto& scenes = held_out.scenes;
  torch::NoGradGuard no_grad;
  ValidationResult r;
  // Per-scene means summed over the scenes (flat_eval's table is their mean),
  // each with its count: a baseline counts where it could be measured.
  enum { kPsnr, kSsim, kLpips, kLpipsN, kCos, kL1, kCosN, kSiLog, kSiLogN, kRough, kRoughN, kOracle, kMean, kMeanN,
         kSwap, kSwapN, kViews, kScenes, kN };
  std::vector<double> sums(kN, 0.0);
  const auto device = pipeline.decoder()->conv2->weight.device();
  const int64_t first = group ? group->rank() : 0, stride = group ? group->world_size() : 1;
  const int64_t n = int64_t(scenes.size());
  for (int64_t i = first; i < n; i += stride) {
    eval::BaselineInputs inputs;
    // The baselines of flat_eval: swap and dataset mean within the scene's own dataset.
    if (const auto partner = held_out.swap_partner(size_t(i))) inputs.swap_with = &scenes[*partner];
    const auto sums_it = held_out.frame_sums.find(held_out.dataset[size_t(i)]);
    if (sums_it != held_out.frame_sums.end()) inputs.frame_sums = &sums_it->second;
    const auto sc = eval::evaluate_scene(pipeline, scenes[size_t(i)], settings, lpips, inputs);
    sums[kPsnr] += sc.psnr;
    sums[kSsim] += sc.ssim;
    if (std::isfinite(sc.lpips)) sums[kLpips] += sc.lpips, sums[kLpipsN] += 1;
    if (std::isfinite(sc.normal_cosine)) sums[kCos] += sc.normal_cosine, sums[kL1] += sc.normal_l1, sums[kCosN] += 1;
    if (std::isfinite(sc.depth_si_log)) sums[kSiLog] += sc.depth_si_log, sums[kSiLogN] += 1;
    if (std::isfinite(sc.planar_roughness)) sums[kRough] += sc.planar_roughness, sums[kRoughN] += 1;
    sums[kOracle] += sc.mean_colour_psnr;
    if (std::isfinite(sc.dataset_mean_psnr)) sums[kMean] += sc.dataset_mean_psnr, sums[kMeanN] += 1;
    if (std::isfinite(sc.swap_psnr)) sums[kSwap] += sc.swap_psnr, sums[kSwapN] += 1;
    sums[kViews] += double(sc.views);
    sums[kScenes] += 1;
    // Grid rows: the first view of each of this rank's first scenes, so that
    // a reader sees whether each held-out scene gets its own layout.
    if (i / stride < grid_views) {
      auto row = validation_grid_row(pipeline, scenes[size_t(i)], settings);
      r.grid = r.grid.defined() ? at::cat({r.grid, row}, 1) : row;
    }
  }
  if (group) sums = distributed::sum_over_ranks(*group, sums, device);
  auto mean = [&](int value, int count) { return sums[size_t(count)] > 0 ? sums[size_t(value)] / sums[size_t(count)] : NAN; };
  r.samples = int64_t(std::llround(sums[kScenes]));
  r.views = int64_t(std::llround(sums[kViews]));
  r.psnr = mean(kPsnr, kScenes);
  r.ssim = mean(kSsim, kScenes);
  r.lpips = mean(kLpips, kLpipsN);
  r.normal_cosine = mean(kCos, kCosN);
  r.normal_l1 = mean(kL1, kCosN);
  r.depth_si_log = mean(kSiLog, kSiLogN);
  r.planar_roughness = mean(kRough, kRoughN);
  r.mean_colour_psnr = mean(kOracle, kScenes);
  r.dataset_mean_psnr = mean(kMean, kMeanN);
  r.swap_psnr = mean(kSwap, kSwapN);
  return r;
}

}  // namespace flat::train
