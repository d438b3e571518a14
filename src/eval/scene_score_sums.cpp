#include "eval/scene_score_sums.h"

#include <cmath>

#include "flat/data/frame_resize.h"
#include "flat/eval/depth_metrics.h"
#include "flat/eval/normal_metrics.h"
#include "eval/mean_of.h"

namespace flat::eval {

SceneScoreSums::SceneScoreSums(const EvalSettings& settings, loss::Lpips lpips, const BaselineInputs& baselines,
                               int64_t H, int64_t W, const at::Device& device)
    : settings_(settings), lpips_(std::move(lpips)), baselines_(baselines), H_(H), W_(W), device_(device) {}

void SceneScoreSums::add(const ViewChunk& c) {
  const auto rgb = c.rendered.rgb.to(at::kCPU, at::kFloat).clamp(0, 1);
  const auto target = c.truth.images.to(at::kFloat);
  add_image_scores(c, rgb, target);
  if (baselines_.swap_with) add_swap(c, rgb);
  if (!lpips_.is_empty()) {
    auto d = eval::lpips(lpips_, c.rendered.rgb.to(at::kFloat).clamp(0, 1), target.to(device_));
    for (int64_t k = 0; k < d.size(0); ++k) lpips_values_.push_back(d[k].item<double>());
  }
  add_geometry(c);
}

void SceneScoreSums::add_image_scores(const ViewChunk& c, const at::Tensor& rgb, const at::Tensor& target) {
  auto p = eval::psnr(rgb, target), q = eval::ssim(rgb, target, settings_.ssim);
  const auto oracle = mean_colour_psnr(target);
  for (int64_t k = 0; k < rgb.size(0); ++k) {
    psnr_.push_back(p[k].item<double>());
    ssim_.push_back(q[k].item<double>());
    mean_colour_.push_back(oracle[k].item<double>());
    if (baselines_.frame_sums)
      if (auto m = baselines_.frame_sums->leave_one_out(c.frames[size_t(k)], target[k]))
        dataset_mean_.push_back(eval::psnr(m->unsqueeze(0), target[k].unsqueeze(0))[0].item<double>());
  }
}

// Swap: the same renders against the other scene's frames of the same index
// (views past its end are not scored).
void SceneScoreSums::add_swap(const ViewChunk& c, const at::Tensor& rgb) {
  const data::Scene& other_scene = *baselines_.swap_with;
  std::vector<int64_t> shared, rows;
  for (size_t k = 0; k < c.frames.size(); ++k)
    if (c.frames[k] < other_scene.size()) {
      shared.push_back(c.frames[k]);
      rows.push_back(int64_t(k));
    }
  if (shared.empty()) return;
  auto other = data::load_frames(other_scene, shared, false, false);
  data::fit_frames(other, other_scene.cameras(shared).intrinsics, H_, W_);
  auto sp = eval::psnr(rgb.index_select(0, at::tensor(rows)), other.images.to(at::kFloat));
  for (int64_t k = 0; k < sp.size(0); ++k) swap_.push_back(sp[k].item<double>());
}

// Normals and depth where the render is opaque enough and a reference exists.
void SceneScoreSums::add_geometry(const ViewChunk& c) {
  const auto& v = c.rendered;
  const auto& gt = c.truth;
  const auto mask = v.alpha.to(at::kCPU, at::kFloat) > settings_.normal_alpha;
  if (gt.normals.defined()) {
    auto acc = normal_accuracy(v.normal.to(at::kCPU, at::kFloat), gt.normals, mask);
    if (acc.valid_pixels > 0) {
      l1_sum_ += acc.mean_l1 * double(acc.valid_pixels);
      cos_sum_ += acc.mean_cosine * double(acc.valid_pixels);
      normal_pixels_ += acc.valid_pixels;
    }
  }
  if (gt.depth.defined() && v.depth.defined()) {
    auto acc = depth_accuracy(v.depth.to(at::kCPU, at::kFloat), gt.depth, mask, gt.normals);
    for (double e : acc.si_log)
      if (std::isfinite(e)) si_log_.push_back(e);
    roughness_sum_ += acc.planar_roughness_sum;
    planar_pixels_ += acc.planar_pixels;
  }
}

void SceneScoreSums::write(SceneScore& r) const {
  r.psnr = mean_of(psnr_);
  r.ssim = mean_of(ssim_);
  r.lpips = mean_of(lpips_values_);
  r.mean_colour_psnr = mean_of(mean_colour_);
  r.dataset_mean_psnr = mean_of(dataset_mean_);
  r.swap_psnr = mean_of(swap_);
  r.normal_pixels = normal_pixels_;
  if (normal_pixels_ > 0) {
    r.normal_l1 = l1_sum_ / double(normal_pixels_);
    r.normal_cosine = cos_sum_ / double(normal_pixels_);
  }
  r.depth_si_log = mean_of(si_log_);
  r.planar_pixels = planar_pixels_;
  if (planar_pixels_ > 0) r.planar_roughness = roughness_sum_ / double(planar_pixels_);
}

}  // namespace flat::eval
