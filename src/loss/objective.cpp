#include "flat/loss/objective.h"

#include "flat/core/error.h"
#include "flat/loss/depth.h"
#include "flat/loss/normal.h"
#include "flat/loss/opacity.h"
#include "flat/loss/photometric.h"
#include "flat/loss/regularisers_2dgs.h"

namespace flat::loss {
namespace {
const at::Tensor& need(const at::Tensor& t, const char* name, const char* term) {
  FLAT_CHECK(t.defined(), std::string("loss '") + term + "' has weight > 0 but input '" + name + "' is missing");
  return t;
}
}  // namespace

Objective::Objective(LossConfig cfg, const at::Device& device, bool bf16_run) : cfg_(std::move(cfg)) {
  const bool bf16 = cfg_.lpips_precision == "bf16" || (cfg_.lpips_precision == "auto" && bf16_run && device.is_cuda());
  lpips_options_ = {.max_size = cfg_.lpips_max_size,
                    .chunk = cfg_.lpips_chunk,
                    .checkpoint = cfg_.lpips_checkpoint,
                    .bf16 = bf16};
  if (cfg_.lambda_perc > 0) {
    lpips_ = Lpips();
    lpips_->load(cfg_.lpips_weights);  // throws naming the file / tensor
    lpips_->to(device);
    lpips_->eval();
  }
}

LossResult Objective::operator()(const LossInputs& in) {
  LossResult r;
  std::vector<at::Tensor> weighted;
  auto add = [&](const char* name, double weight, const at::Tensor& value) {
    r.terms[name] = value.detach();
    weighted.push_back(weight * value);
  };
  if (cfg_.lambda_rgb > 0) add("rgb", cfg_.lambda_rgb, l2_loss(need(in.rgb, "rgb", "rgb"), need(in.target_rgb, "target_rgb", "rgb")));
  if (cfg_.lambda_perc > 0) {
    auto d = lpips_distance(lpips_, need(in.rgb, "rgb", "lpips"), need(in.target_rgb, "target_rgb", "lpips"),
                            lpips_options_);
    add("lpips", cfg_.lambda_perc, d.mean());
  }
  if (cfg_.lambda_depth > 0) {
    const auto& depth = need(in.depth, "depth", "depth");
    const auto& target = need(in.target_depth, "target_depth", "depth");
    // Valid: a finite positive target, and a rendered depth (something was hit).
    auto mask = at::isfinite(target) & (target > 0) & (depth.detach() > 1e-6);
    auto t = at::where(mask, target, at::ones_like(target));
    auto target_disp = cfg_.depth_target == "disparity" ? t : depth_to_disparity(t);
    add("depth", cfg_.lambda_depth, disparity_loss(depth_to_disparity(depth), target_disp, mask));
  }
  if (cfg_.lambda_normal > 0) {
    add("normal", cfg_.lambda_normal,
        normal_loss(need(in.normal, "normal", "normal"), need(in.target_normal, "target_normal", "normal"),
                    need(in.alpha, "alpha", "normal"), cfg_.normal_alpha_threshold));
  }
  if (cfg_.lambda_opacity > 0)
    add("opacity", cfg_.lambda_opacity, opacity_loss(need(in.opacities, "opacities", "opacity")));
  if (cfg_.lambda_normal_consistency > 0) {
    add("normal_consistency", cfg_.lambda_normal_consistency,
        normal_consistency_loss(need(in.normal, "normal", "normal_consistency"),
                                need(in.depth, "depth", "normal_consistency"),
                                need(in.alpha, "alpha", "normal_consistency"),
                                need(in.intrinsics, "intrinsics", "normal_consistency")));
  }
  if (cfg_.lambda_distortion > 0)
    add("distortion", cfg_.lambda_distortion, depth_distortion_loss(need(in.distortion, "distortion", "distortion")));
  FLAT_CHECK(!weighted.empty(), "loss: every weight is 0, nothing to optimise");
  r.total = weighted[0];
  for (size_t i = 1; i < weighted.size(); ++i) r.total = r.total + weighted[i];
  r.terms["total"] = r.total.detach();
  return r;
}

}  // namespace flat::loss
