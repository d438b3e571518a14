#include "flat/pipeline/scene_pipeline.h"

#include <vector>

#include <ATen/core/grad_mode.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/gaussians/rasterize_gaussians.h"
#include "flat/loss/regularisers_2dgs.h"
#include "flat/primitives/ray_gaussians.h"
#include "flat/surfels/rasterize_surfels.h"

namespace flat::pipeline {

RenderedViews normalise_by_alpha(const render::RenderOutput& out) {
  RenderedViews v;
  v.rgb = out.rgb;
  v.alpha = out.alpha;
  v.max_weight = out.max_weight;
  auto has = out.alpha > kMinAlphaForGeometry;
  auto safe_alpha = at::where(has, out.alpha, at::ones_like(out.alpha));
  v.depth = at::where(has, out.depth / safe_alpha, at::zeros_like(out.depth));
  // 3DGS renders no normal: the caller derives it from this depth.
  if (out.normal.defined()) v.normal = at::where(has, out.normal / safe_alpha, at::zeros_like(out.normal));
  return v;
}

primitives::ScenePrimitives prune(const primitives::ScenePrimitives& scene, double min_opacity) {
  check_shape(scene.opacities(), {-1}, "prune: opacities", "(N): one scene, no batch dimension");
  if (min_opacity <= 0) return scene;
  return scene.index_select((scene.opacities().detach() >= min_opacity).nonzero().squeeze(1));
}

render::RenderOutput rasterize_scene(const primitives::ScenePrimitives& scene, const camera::Cameras& cams,
                                     int64_t height, int64_t width, const render::RasterSettings& settings) {
  if (scene.is_triangles()) {
    const auto& t = scene.triangles;
    return render::rasterize(t.vertices, t.colors, t.opacities, t.sigmas, cams, height, width, settings);
  }
  const auto& g = scene.gaussians;
  if (scene.representation == primitives::kGaussians3d)
    return gaussians::rasterize_gaussians(g.means, g.scales, g.rotations, g.colors, g.opacities, cams, height, width,
                                          settings);
  return surfels::rasterize_surfels(g.means, g.scales, g.rotations, g.colors, g.opacities, cams, height, width,
                                    settings);
}

primitives::HeadChannels PipelineConfig::channels() const {
  if (representation == primitives::kGaussians3d) return primitives::gaussian_channels(3);
  if (representation == primitives::kSurfels2d) return primitives::gaussian_channels(2);
  return triangles.channels();
}

ScenePipeline::ScenePipeline(PipelineConfig config, model::SceneDecoder decoder)
    : config_(std::move(config)), decoder_(std::move(decoder)) {
  FLAT_CHECK(!decoder_.is_empty(), "ScenePipeline: no scene decoder");
  const std::string layout = config_.representation == primitives::kTriangles
                                 ? "the triangle layout '" + config_.triangles.parameterisation + "'"
                                 : "the " + config_.representation + " layout";
  FLAT_CHECK(decoder_->channels().total == config_.channels().total,
             "ScenePipeline: the decoder's heads give " + std::to_string(decoder_->channels().total) +
                 " channels but " + layout + " needs " + std::to_string(config_.channels().total));
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

// Raw head outputs (B,C,t,H/2,W/2) of `cams` (B*t anchors) -> primitives.
primitives::ScenePrimitives build_primitives(const at::Tensor& raw, const camera::Cameras& cams,
                                             const PipelineConfig& cfg) {
  const int64_t h = raw.size(3) * 2, w = raw.size(4) * 2;
  if (cfg.representation == primitives::kTriangles)
    return primitives::ScenePrimitives::of(primitives::build_triangles(raw, cams, h, w, cfg.triangles));
  const int64_t scales = cfg.representation == primitives::kGaussians3d ? 3 : 2;
  return primitives::ScenePrimitives::of(primitives::build_gaussians(raw, cams, h, w, cfg.triangles, scales));
}
}  // namespace

primitives::ScenePrimitives ScenePipeline::decode(const SceneInput& in, bool streaming) {
  const int64_t B = in.video_latents.size(0), T = check_input(in);
  const auto device = decoder_->conv2->weight.device();
  auto latents = in.video_latents.to(device, at::kFloat);
  auto camera_latents = in.camera_latents.defined() ? in.camera_latents.to(device, at::kFloat) : at::Tensor();
  auto raw = decoder_->forward(latents, camera_latents, streaming);  // (B,C,T,h*4,w*4)
  FLAT_CHECK(raw.size(2) == T, "pipeline: decoded " + std::to_string(raw.size(2)) + " frames, expected " +
                                   std::to_string(T));
  camera::Cameras anchors{in.input_intrinsics.reshape({B * T, 4}).to(device, at::kFloat),
                          in.input_c2w.reshape({B * T, 4, 4}).to(device, at::kFloat)};
  return build_primitives(raw, anchors, config_);
}

primitives::ScenePrimitives ScenePipeline::decode_to(const SceneInput& in, const at::Device& out_device) {
  const int64_t B = in.video_latents.size(0), T = check_input(in);
  at::NoGradGuard no_grad;
  const auto device = decoder_->conv2->weight.device();
  auto latents = in.video_latents.to(device, at::kFloat);
  auto camera_latents = in.camera_latents.defined() ? in.camera_latents.to(device, at::kFloat) : at::Tensor();
  std::vector<primitives::ScenePrimitives> parts;
  int64_t first = 0;
  decoder_->forward_chunks(latents, camera_latents, [&](const at::Tensor& raw) {
    const int64_t t = raw.size(2);
    FLAT_CHECK(first + t <= T, "pipeline: the decoder gave more than " + std::to_string(T) + " frames");
    camera::Cameras anchors{in.input_intrinsics.narrow(1, first, t).reshape({B * t, 4}).to(device, at::kFloat),
                            in.input_c2w.narrow(1, first, t).reshape({B * t, 4, 4}).to(device, at::kFloat)};
    parts.push_back(build_primitives(raw, anchors, config_).map(
        [&](const at::Tensor& x) { return x.to(out_device, at::kFloat); }));
    first += t;
  });
  FLAT_CHECK(first == T, "pipeline: decoded " + std::to_string(first) + " frames, expected " + std::to_string(T));
  return primitives::cat(parts, 1);
}

RenderedViews ScenePipeline::render(const primitives::ScenePrimitives& scene, const camera::Cameras& cams,
                                    int64_t height, int64_t width) const {
  return render(scene, cams, height, width, config_.prune_opacity);
}

RenderedViews ScenePipeline::render(const primitives::ScenePrimitives& scene, const camera::Cameras& cams,
                                    int64_t height, int64_t width, double min_opacity) const {
  FLAT_CHECK(scene.representation == config_.representation,
             "pipeline: a " + scene.representation + " scene given to a " + config_.representation + " pipeline");
  const auto kept = prune(scene, min_opacity);
  render::RenderOutput out = rasterize_scene(kept, cams, height, width, config_.raster);
  auto views = normalise_by_alpha(out);
  // 3DGS has no surface normal: the paper takes its normals from the rendered
  // depth by finite differences (zero outside the covered pixels).
  if (!views.normal.defined()) {
    const auto& d = views.depth;
    views.normal = at::where(views.alpha > kMinAlphaForGeometry,
                             loss::normals_from_depth(d, cams.intrinsics.to(d.device(), d.scalar_type())),
                             at::zeros_like(d).expand({-1, 3, -1, -1}));
  }
  views.distortion = out.distortion;
  views.triangles = kept.size();
  return views;
}

}  // namespace flat::pipeline
