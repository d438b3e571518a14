#include "flat/pipeline/scene_pipeline.h"

#include <vector>

#include <ATen/core/grad_mode.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::pipeline {

RenderedViews normalise_by_alpha(const render::RenderOutput& out) {
  RenderedViews v;
  v.rgb = out.rgb;
  v.alpha = out.alpha;
  v.max_weight = out.max_weight;
  auto has = out.alpha > kMinAlphaForGeometry;
  auto safe_alpha = at::where(has, out.alpha, at::ones_like(out.alpha));
  v.depth = at::where(has, out.depth / safe_alpha, at::zeros_like(out.depth));
  v.normal = at::where(has, out.normal / safe_alpha, at::zeros_like(out.normal));
  return v;
}

primitives::TriangleSoup prune(const primitives::TriangleSoup& scene, double min_opacity) {
  check_shape(scene.vertices, {-1, 3, 3}, "prune: vertices", "(N,3,3)");
  if (min_opacity <= 0) return scene;
  auto keep = (scene.opacities.detach() >= min_opacity).nonzero().squeeze(1);
  return {scene.vertices.index_select(0, keep), scene.colors.index_select(0, keep),
          scene.opacities.index_select(0, keep), scene.sigmas.index_select(0, keep)};
}

ScenePipeline::ScenePipeline(PipelineConfig config, model::SceneDecoder decoder)
    : config_(std::move(config)), decoder_(std::move(decoder)) {
  FLAT_CHECK(!decoder_.is_empty(), "ScenePipeline: no scene decoder");
  FLAT_CHECK(decoder_->channels().total == config_.triangles.channels().total,
             "ScenePipeline: the decoder's heads give " + std::to_string(decoder_->channels().total) +
                 " channels but the triangle layout '" + config_.triangles.parameterisation + "' needs " +
                 std::to_string(config_.triangles.channels().total));
}

namespace {
// Checks the input's shapes; returns T = 1 + 4(T'-1), the frames it decodes to.
int64_t check_input(const SceneInput& in) {
  check_shape(in.video_latents, {-1, 16, -1, -1, -1}, "pipeline: video latents", "(B,16,T',h,w)");
  const int64_t B = in.video_latents.size(0), T = 1 + 4 * (in.video_latents.size(2) - 1);
  check_shape(in.input_intrinsics, {B, T, 4}, "pipeline: input intrinsics",
              "(B,T,4) with T = 1+4(T'-1) = " + std::to_string(T));
  check_shape(in.input_c2w, {B, T, 4, 4}, "pipeline: input camera-to-world", "(B,T,4,4)");
  return T;
}
}  // namespace

primitives::TriangleSoup ScenePipeline::decode(const SceneInput& in, bool streaming) {
  const int64_t B = in.video_latents.size(0), T = check_input(in);
  const auto device = decoder_->conv2->weight.device();
  auto latents = in.video_latents.to(device, at::kFloat);
  auto camera_latents = in.camera_latents.defined() ? in.camera_latents.to(device, at::kFloat) : at::Tensor();
  auto raw = decoder_->forward(latents, camera_latents, streaming);  // (B,C,T,h*4,w*4)
  FLAT_CHECK(raw.size(2) == T, "pipeline: decoded " + std::to_string(raw.size(2)) + " frames, expected " +
                                   std::to_string(T));
  const int64_t image_h = raw.size(3) * 2, image_w = raw.size(4) * 2;
  camera::Cameras anchors{in.input_intrinsics.reshape({B * T, 4}).to(device, at::kFloat),
                          in.input_c2w.reshape({B * T, 4, 4}).to(device, at::kFloat)};
  return primitives::build_triangles(raw, anchors, image_h, image_w, config_.triangles);
}

primitives::TriangleSoup ScenePipeline::decode_to(const SceneInput& in, const at::Device& out_device) {
  const int64_t B = in.video_latents.size(0), T = check_input(in);
  at::NoGradGuard no_grad;
  const auto device = decoder_->conv2->weight.device();
  auto latents = in.video_latents.to(device, at::kFloat);
  auto camera_latents = in.camera_latents.defined() ? in.camera_latents.to(device, at::kFloat) : at::Tensor();
  std::vector<primitives::TriangleSoup> parts;
  int64_t first = 0;
  decoder_->forward_chunks(latents, camera_latents, [&](const at::Tensor& raw) {
    const int64_t t = raw.size(2);
    FLAT_CHECK(first + t <= T, "pipeline: the decoder gave more than " + std::to_string(T) + " frames");
    camera::Cameras anchors{in.input_intrinsics.narrow(1, first, t).reshape({B * t, 4}).to(device, at::kFloat),
                            in.input_c2w.narrow(1, first, t).reshape({B * t, 4, 4}).to(device, at::kFloat)};
    auto tri = primitives::build_triangles(raw, anchors, raw.size(3) * 2, raw.size(4) * 2, config_.triangles);
    parts.push_back({tri.vertices.to(out_device, at::kFloat), tri.colors.to(out_device, at::kFloat),
                     tri.opacities.to(out_device, at::kFloat), tri.sigmas.to(out_device, at::kFloat)});
    first += t;
  });
  FLAT_CHECK(first == T, "pipeline: decoded " + std::to_string(first) + " frames, expected " + std::to_string(T));
  auto cat = [&](auto member) {
    std::vector<at::Tensor> xs;
    for (const auto& p : parts) xs.push_back(p.*member);
    return at::cat(xs, 1);
  };
  return {cat(&primitives::TriangleSoup::vertices), cat(&primitives::TriangleSoup::colors),
          cat(&primitives::TriangleSoup::opacities), cat(&primitives::TriangleSoup::sigmas)};
}

RenderedViews ScenePipeline::render(const primitives::TriangleSoup& scene, const camera::Cameras& cams,
                                    int64_t height, int64_t width) const {
  auto kept = prune(scene, config_.prune_opacity);
  auto out = render::rasterize(kept.vertices, kept.colors, kept.opacities, kept.sigmas, cams, height, width,
                               config_.raster);
  auto views = normalise_by_alpha(out);
  views.triangles = kept.vertices.size(0);
  return views;
}

}  // namespace flat::pipeline
