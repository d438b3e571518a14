#include "flat/train/train_step.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <string>
#include <vector>

#include <ATen/autocast_mode.h>
#include <c10/util/ApproximateClock.h>
#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/train/random_background.h"

namespace flat::train {

namespace {

using Clock = std::chrono::steady_clock;

// Ends a phase: waits for the device when timing, adds the time.
struct PhaseClock {
  StepTimes* times;
  at::Device device;
  Clock::time_point start = Clock::now();
  void lap(double StepTimes::*field) {
    if (!times) return;
    if (device.is_cuda()) torch::cuda::synchronize(device.index() < 0 ? 0 : device.index());
    const auto now = Clock::now();
    times->*field += std::chrono::duration<double>(now - start).count();
    times->phase_end_ns.push_back(int64_t(c10::getTime()));
    start = now;
  }
};

// " name" for each tensor holding a NaN or Inf.
std::string nonfinite_names(const std::vector<std::pair<const char*, at::Tensor>>& tensors) {
  std::string out;
  for (const auto& [name, t] : tensors)
    if (!at::isfinite(t.detach()).all().item<bool>()) out += std::string(" ") + name;
  return out;
}

// Non-finite primitives (NaN latents, a diverged model): "" when all are
// finite (one sync), else "decoded <representation>: <tensors>".
std::string nonfinite_decoded(const primitives::ScenePrimitives& scene) {
  const auto named = scene.named_tensors();
  at::Tensor finite;
  for (const auto& [name, t] : named) finite = finite.defined() ? finite & at::isfinite(t).all() : at::isfinite(t).all();
  if (finite.item<bool>()) return "";
  std::vector<std::pair<const char*, at::Tensor>> tensors;
  for (const auto& [name, t] : named) tensors.push_back({name.c_str(), t});
  return "decoded " + scene.representation + ":" + nonfinite_names(tensors);
}

// Phase split: the rasterizer and losses see leaf copies of the decoded
// primitives, so that their backward and the decoder's are timed apart.
struct LeafCopies {
  std::vector<at::Tensor> decoded, leaves;
  primitives::ScenePrimitives scene;  // made of `leaves`
};

LeafCopies leaf_copies(const primitives::ScenePrimitives& scene) {
  LeafCopies c;
  for (const auto& [name, t] : scene.named_tensors()) {
    c.decoded.push_back(t);
    c.leaves.push_back(t.detach().requires_grad_(true));
  }
  c.scene = scene.with_tensors(c.leaves);
  return c;
}

// The leaves' gradients carried on into the decoder.
void backward_into_decoder(const LeafCopies& c) {
  std::vector<at::Tensor> outputs, grads;
  for (size_t i = 0; i < c.decoded.size(); ++i) {
    if (!c.leaves[i].grad().defined() || !c.decoded[i].requires_grad()) continue;
    outputs.push_back(c.decoded[i]);
    grads.push_back(c.leaves[i].grad());
  }
  if (!outputs.empty()) torch::autograd::backward(outputs, grads);
}

// Scene b's renders beside its targets (depth and normals where it has them).
loss::LossInputs loss_inputs(const data::Batch& batch, int64_t b, const pipeline::RenderedViews& views,
                             const primitives::ScenePrimitives& scene, const at::Device& device) {
  loss::LossInputs li;
  li.rgb = views.rgb;
  li.target_rgb = batch.target_images[b].to(device, at::kFloat);
  li.alpha = views.alpha;
  li.depth = views.depth;
  li.normal = views.normal;
  if (batch.target_depth.defined() && batch.depth_present[b].item<bool>())
    li.target_depth = batch.target_depth[b].to(device, at::kFloat);
  if (batch.target_normals.defined() && batch.normals_present[b].item<bool>())
    li.target_normal = batch.target_normals[b].to(device, at::kFloat);
  li.opacities = scene.opacities()[b];
  li.distortion = views.distortion;
  li.intrinsics = batch.target_intrinsics[b].to(device, at::kFloat);
  return li;
}

// The objective averaged over the batch's scenes; each term's value, averaged
// too, is added to `terms`.
at::Tensor batch_loss(loss::Objective& objective, const data::Batch& batch,
                      const std::vector<pipeline::RenderedViews>& rendered, const primitives::ScenePrimitives& scene,
                      const at::Device& device, std::map<std::string, double>& terms) {
  const int64_t B = int64_t(rendered.size());
  at::Tensor total;
  for (int64_t b = 0; b < B; ++b) {
    auto result = objective(loss_inputs(batch, b, rendered[size_t(b)], scene, device));
    total = total.defined() ? total + result.total / double(B) : result.total / double(B);
    // Every term of this scene in one device-to-host copy (one sync, not one per term).
    std::vector<std::string> names;
    std::vector<at::Tensor> values;
    for (const auto& [name, value] : result.terms) {
      names.push_back(name);
      values.push_back(value.reshape({}).to(at::kDouble));
    }
    const auto host = at::stack(values).cpu();
    const double* h = host.data_ptr<double>();
    for (size_t i = 0; i < names.size(); ++i) terms[names[i]] += h[i] / double(B);
  }
  return total;
}

// Each scene of `scene` rendered into its target views, pruned below
// `prune_opacity` (< 0: the pipeline's), over random backgrounds drawn from
// background_seed when >= 0; the rendered primitives are added to `triangles`.
std::vector<pipeline::RenderedViews> render_targets(const pipeline::ScenePipeline& pipeline,
                                                    const primitives::ScenePrimitives& scene, const data::Batch& batch,
                                                    const at::Device& device, int64_t background_seed,
                                                    double prune_opacity, int64_t& triangles) {
  std::vector<pipeline::RenderedViews> rendered;
  const int64_t H = batch.target_images.size(3), W = batch.target_images.size(4);
  for (int64_t b = 0; b < scene.batch(); ++b) {
    rendered.push_back(pipeline.render(scene.scene(b), batch.target_cameras(b).to(device), H, W,
                                       prune_opacity >= 0 ? prune_opacity : pipeline.config().prune_opacity));
    triangles += rendered.back().triangles;
    if (background_seed >= 0)
      use_random_background(rendered.back(), pipeline.config().raster.background,
                            uint64_t(background_seed) * 1000003ull + uint64_t(b));
  }
  return rendered;
}

// Which loss terms and which renders are not finite.
std::string nonfinite_loss(const std::map<std::string, double>& terms,
                           const std::vector<pipeline::RenderedViews>& rendered) {
  std::string bad_terms, views;
  for (const auto& [name, value] : terms)
    if (name != "total" && !std::isfinite(value)) bad_terms += " " + name;
  for (const auto& v : rendered)
    views += nonfinite_names({{"rgb", v.rgb}, {"alpha", v.alpha}, {"depth", v.depth}, {"normal", v.normal}});
  return "loss terms:" + (bad_terms.empty() ? std::string(" (none)") : bad_terms) +
         "; rendered:" + (views.empty() ? std::string(" all finite") : views);
}

}  // namespace

StepResult forward_backward(pipeline::ScenePipeline& pipeline, loss::Objective& objective, const data::Batch& batch,
                            bool bf16, StepTimes* times, int64_t background_seed, double prune_opacity) {
  const auto device = pipeline.decoder()->conv2->weight.device();
  FLAT_CHECK(batch.video_latents.defined(), "training step: the batch has no latents (data.latents: true)");
  PhaseClock clock{times, device};
  StepResult r;
  AutocastScope autocast(bf16 && device.is_cuda(), device.type());

  pipeline::SceneInput in{batch.video_latents, batch.camera_latents, batch.input_intrinsics, batch.input_c2w};
  auto scene = pipeline.decode(in);
  clock.lap(&StepTimes::decode_forward);
  // The rasterizer refuses non-finite primitives: the step is skipped like a
  // non-finite loss.
  r.nonfinite = nonfinite_decoded(scene);
  if (!r.nonfinite.empty()) {
    r.finite = false;
    r.loss = NAN;
    return r;
  }

  const auto leaf = leaf_copies(scene);
  const auto rendered =
      render_targets(pipeline, leaf.scene, batch, device, background_seed, prune_opacity, r.triangles);
  clock.lap(&StepTimes::render_forward);

  const at::Tensor total = batch_loss(objective, batch, rendered, leaf.scene, device, r.terms);
  r.loss = r.terms["total"];
  clock.lap(&StepTimes::loss_forward);
  if (!std::isfinite(r.loss)) {
    r.finite = false;
    r.nonfinite = nonfinite_loss(r.terms, rendered);
    return r;
  }

  total.backward();
  clock.lap(&StepTimes::render_loss_backward);
  backward_into_decoder(leaf);
  clock.lap(&StepTimes::decoder_backward);
  return r;
}

StepResult score_decoded(pipeline::ScenePipeline& pipeline, loss::Objective& objective, const data::Batch& batch,
                         const primitives::ScenePrimitives& scene, int64_t background_seed, double prune_opacity) {
  at::NoGradGuard no_grad;
  StepResult r;
  const auto device = pipeline.decoder()->conv2->weight.device();
  const auto rendered = render_targets(pipeline, scene, batch, device, background_seed, prune_opacity, r.triangles);
  batch_loss(objective, batch, rendered, scene, device, r.terms);
  r.loss = r.terms["total"];
  r.finite = std::isfinite(r.loss);
  if (!r.finite) r.nonfinite = nonfinite_loss(r.terms, rendered);
  return r;
}

double training_prune_opacity(double target, int64_t warmup_steps, int64_t step) {
  if (warmup_steps <= 0 || step >= warmup_steps) return target;
  return target * double(std::max<int64_t>(step, 0)) / double(warmup_steps);
}

}  // namespace flat::train
