#include "flat/eval/scene_evaluation.h"

#include <chrono>

#include <torch/torch.h>

#include "flat/core/autocast_scope.h"
#include "flat/core/error.h"
#include "flat/data/frame_resize.h"
#include "flat/data/scene_frames.h"
#include "flat/data/scene_latents.h"
#include "eval/scene_score_sums.h"

namespace flat::eval {

std::string EvalSettings::fingerprint() const {
  return "views=" + views + " max_views=" + std::to_string(max_views) + " window=" + std::to_string(window) +
         " size=" + std::to_string(height) + "x" + std::to_string(width) + " ssim=" + ssim_convention_name(ssim) +
         " normal_alpha=" + std::to_string(normal_alpha) + (latent_set.empty() ? "" : " latent_set=" + latent_set);
}

std::vector<int64_t> evaluation_views(const data::Scene& scene, const EvalSettings& s) {
  FLAT_CHECK(s.views == "scene" || s.views == "window" || s.views == "unseen",
             "views: expected scene, window or unseen, got '" + s.views + "'");
  FLAT_CHECK(scene.latents.present(), scene.json_path() + ": the scene has no precomputed latents (run flat_latents)");
  FLAT_CHECK(s.window >= 0 && s.window < int64_t(scene.latents.windows.size()),
             scene.json_path() + ": latent window " + std::to_string(s.window) + " does not exist (the scene has " +
                 std::to_string(scene.latents.windows.size()) + ")");
  const auto& w = scene.latents.windows[size_t(s.window)];
  std::vector<int64_t> frames;
  for (int64_t f = 0; f < scene.size(); ++f) {
    const bool inside = f >= w.start && f < w.start + w.count;
    if (s.views == "scene" || (s.views == "window" && inside) || (s.views == "unseen" && !inside)) frames.push_back(f);
  }
  FLAT_CHECK(!frames.empty(), scene.json_path() + ": no '" + s.views + "' views to evaluate (" +
                                  std::to_string(scene.size()) + " frames, window " + std::to_string(w.start) + "+" +
                                  std::to_string(w.count) + ")");
  if (s.max_views > 0 && int64_t(frames.size()) > s.max_views) {
    std::vector<int64_t> picked;
    const double step = double(frames.size() - 1) / double(std::max<int64_t>(1, s.max_views - 1));
    for (int64_t i = 0; i < s.max_views; ++i) picked.push_back(frames[size_t(std::llround(i * step))]);
    frames = picked;
  }
  return frames;
}

namespace {

// The evaluation size: the settings', else the latents' frame size.
std::pair<int64_t, int64_t> evaluation_size(const data::Scene& scene, const EvalSettings& s) {
  return {s.height > 0 ? s.height : scene.latents.height, s.width > 0 ? s.width : scene.latents.width};
}

}  // namespace

void add_frame_sums(FrameSums& sums, const data::Scene& scene, const EvalSettings& s) {
  const auto frames = evaluation_views(scene, s);
  const auto [H, W] = evaluation_size(scene, s);
  for (size_t c0 = 0; c0 < frames.size(); c0 += size_t(s.render_chunk)) {
    const std::vector<int64_t> part(frames.begin() + long(c0),
                                    frames.begin() + long(std::min(frames.size(), c0 + size_t(s.render_chunk))));
    auto gt = data::load_frames(scene, part, false, false);
    data::fit_frames(gt, scene.cameras(part).intrinsics, H, W);
    for (size_t k = 0; k < part.size(); ++k) sums.add(part[k], gt.images[int64_t(k)].to(at::kFloat));
  }
}

pipeline::SceneInput window_input(const data::Scene& scene, int64_t window, const std::string& camera_rays) {
  FLAT_CHECK(window >= 0 && window < int64_t(scene.latents.windows.size()),
             scene.json_path() + ": latent window " + std::to_string(window) + " does not exist (the scene has " +
                 std::to_string(scene.latents.windows.size()) + ")");
  const auto& win = scene.latents.windows[size_t(window)];
  auto latents = data::read_window_latents(scene, size_t(window), camera_rays);
  std::vector<int64_t> frames;
  for (int64_t i = 0; i < win.count; ++i) frames.push_back(win.start + i);
  const auto cams = scene.cameras(frames);
  pipeline::SceneInput in;
  in.video_latents = latents.video.unsqueeze(0).to(at::kFloat);
  if (latents.camera.defined()) in.camera_latents = latents.camera.unsqueeze(0).to(at::kFloat);
  in.input_intrinsics = cams.intrinsics.unsqueeze(0);
  in.input_c2w = cams.c2w.unsqueeze(0);
  return in;
}

namespace {

// The window decoded to float32 primitives; NaN or infinite ones are an
// error naming the scene and the tensor.
primitives::ScenePrimitives decode_window(pipeline::ScenePipeline& pipeline, const data::Scene& scene,
                                          const EvalSettings& s, const at::Device& device) {
  const auto in = window_input(scene, s.window, pipeline.config().model.camera_rays);
  primitives::ScenePrimitives prims;
  {
    AutocastScope autocast(s.bf16 && device.is_cuda(), device.type());
    prims = pipeline.decode(in, s.streaming).scene(0).map([](const at::Tensor& t) { return t.to(at::kFloat); });
  }
  for (const auto& [name, t] : prims.named_tensors())
    FLAT_CHECK(at::isfinite(t).all().item<bool>(),
               scene.json_path() + ": the decoded " + prims.representation + " hold NaN or infinite " + name);
  return prims;
}

// The views `frames` rendered at H x W beside their ground truth.
ViewChunk render_views(pipeline::ScenePipeline& pipeline, const primitives::ScenePrimitives& prims,
                       const data::Scene& scene, std::vector<int64_t> frames, const EvalSettings& s, int64_t H,
                       int64_t W, const at::Device& device) {
  ViewChunk c;
  c.truth = data::load_frames(scene, frames, scene.has_depth, scene.has_normals);
  auto intr = data::fit_frames(c.truth, scene.cameras(frames).intrinsics, H, W);
  camera::Cameras cams{intr.to(device), scene.cameras(frames).c2w.to(device)};
  {
    AutocastScope autocast(s.bf16 && device.is_cuda(), device.type());
    c.rendered = pipeline.render(prims, cams, H, W);
  }
  c.frames = std::move(frames);
  return c;
}

}  // namespace

SceneScore evaluate_scene(pipeline::ScenePipeline& pipeline, const data::Scene& scene, const EvalSettings& s,
                          loss::Lpips lpips, const BaselineInputs& baselines) {
  const auto t0 = std::chrono::steady_clock::now();
  torch::NoGradGuard no_grad;
  SceneScore r;
  r.scene = scene.name;
  r.dir = scene.dir;
  r.latent_encoder = scene.latents.encoder;
  const auto frames = evaluation_views(scene, s);
  const auto& win = scene.latents.windows[size_t(s.window)];
  const auto [H, W] = evaluation_size(scene, s);
  const auto device = pipeline.decoder()->conv2->weight.device();

  const auto prims = decode_window(pipeline, scene, s, device);
  r.triangles = pipeline::prune(prims, pipeline.config().prune_opacity).size();

  // Render and score the views, a chunk at a time.
  if (baselines.swap_with) r.swap_scene = baselines.swap_with->name;
  SceneScoreSums sums(s, lpips, baselines, H, W, device);
  for (size_t c0 = 0; c0 < frames.size(); c0 += size_t(s.render_chunk)) {
    std::vector<int64_t> part(frames.begin() + long(c0),
                              frames.begin() + long(std::min(frames.size(), c0 + size_t(s.render_chunk))));
    sums.add(render_views(pipeline, prims, scene, std::move(part), s, H, W, device));
  }
  r.views = int64_t(frames.size());
  for (auto f : frames) r.unseen_views += (f < win.start || f >= win.start + win.count) ? 1 : 0;
  sums.write(r);
  r.ok = true;
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

}  // namespace flat::eval
