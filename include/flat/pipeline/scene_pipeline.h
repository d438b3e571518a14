// The one path from latents to rendered views (paper, Pipeline Overview):
//
//   video latents + camera latents + input cameras
//     -> model::SceneDecoder (adapter, Wan decoder without the last x2, heads)
//     -> primitives::build_triangles (ray-centred, one triangle per 2x2 block)
//        (or build_gaussians: the 3DGS / 2DGS baselines, pipeline.representation)
//     -> prune (opacity below a threshold; paper: 0.4 at the high-resolution stage)
//     -> render::rasterize into target cameras (gaussians:: / surfels:: rasterizers;
//        3DGS normals from depth finite differences, as the paper)
//     -> RenderedViews with depth and normals divided by alpha
//
// Training, validation, flat_infer, flat_eval and the mesh post-optimisation
// all call this, so model and render never meet anywhere else and no caller
// divides depth by alpha itself.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"
#include "flat/core/config.h"
#include "flat/model/scene_decoder.h"
#include "flat/primitives/head_channels.h"
#include "flat/primitives/ray_triangles.h"
#include "flat/primitives/scene_primitives.h"
#include "flat/render/rasterize.h"

namespace flat::pipeline {

struct PipelineConfig {
  // "triangles" (the paper), or the Table 1 baselines "3dgs" / "2dgs": the same
  // decoder, data and losses with Gaussian heads and rasterizers.
  std::string representation = primitives::kTriangles;
  model::SceneDecoderConfig model;
  // The triangles' parameterisation; its depth_*, init_scale, shape_min,
  // colour_activation and opacity_shift also configure the Gaussian heads.
  primitives::TriangleParamConfig triangles;
  // The rasterizer settings; 3dgs and 2dgs read their compositing part
  // (render::CompositingSettings) alone, the window and culling keys are the
  // triangles'.
  render::RasterSettings raster;
  // Triangles with opacity below this are removed before rendering (no
  // gradient reaches them in that step). 0 keeps every triangle.
  double prune_opacity = 0.0;

  template <class V>
  void visit(V& v) {
    v.field("representation", representation,
            config::one_of({primitives::kTriangles, primitives::kGaussians3d, primitives::kSurfels2d}),
            "primitives: triangles | 3dgs | 2dgs (the paper's Table 1 baselines)");
    v.section("model", model);
    v.section("triangles", triangles);
    v.section("raster", raster);
    v.field("prune_opacity", prune_opacity, config::range(0.0, 1.0),
            "remove primitives below this opacity before rendering (paper: 0.4 at 768p)");
  }
  // The heads' channel layout for this representation.
  primitives::HeadChannels channels() const;
};

// A batch of scenes to decode: latents and the cameras of the T input frames.
struct SceneInput {
  at::Tensor video_latents;     // (B,16,T',h,w), normalised
  at::Tensor camera_latents;    // (B,32,T',h,w) or undefined (no camera conditioning)
  at::Tensor input_intrinsics;  // (B,T,4) normalised, T = 1 + 4(T'-1)
  at::Tensor input_c2w;         // (B,T,4,4)
};

struct RenderedViews {
  at::Tensor rgb;     // (V,3,H,W)
  at::Tensor alpha;   // (V,1,H,W)
  at::Tensor depth;   // (V,1,H,W) alpha-normalised (expected depth of what is hit); 0 where alpha <= min_alpha
  at::Tensor normal;  // (V,3,H,W) alpha-normalised camera-space normal; 0 where alpha <= min_alpha
  at::Tensor distortion;  // (V,1,H,W) 2DGS depth distortion map (representation 2dgs only)
  at::Tensor max_weight;  // (N,) largest blending weight per primitive (no gradient)
  int64_t triangles = 0;  // primitives rendered (after pruning)
};

// Below this alpha a pixel has no depth or normal (division would amplify noise).
inline constexpr double kMinAlphaForGeometry = 1e-4;

// Depth and normal divided by alpha where alpha > kMinAlphaForGeometry (an
// undefined normal, 3DGS's, stays undefined).
RenderedViews normalise_by_alpha(const render::RenderOutput& out);

// One scene (no batch dimension) through the rasterizer of its representation
// (render::rasterize, gaussians::rasterize_gaussians or
// surfels::rasterize_surfels); the raw outputs (3DGS: normal undefined).
render::RenderOutput rasterize_scene(const primitives::ScenePrimitives& scene, const camera::Cameras& cams,
                                     int64_t height, int64_t width, const render::RasterSettings& settings);

// The scene's primitives whose opacity is >= min_opacity (a copy through
// index_select, differentiable for the kept ones). scene: one scene (no batch
// dimension). min_opacity <= 0 returns the scene as is.
primitives::ScenePrimitives prune(const primitives::ScenePrimitives& scene, double min_opacity);

class ScenePipeline {
 public:
  // The decoder is shared (a module holder): the trainer owns and optimises it.
  ScenePipeline(PipelineConfig config, model::SceneDecoder decoder);

  // Decodes B scenes: (B, N = T*H/2*W/2) triangles; the image size of the
  // input frames is 8x the latent's. streaming: bounded-memory decoding
  // (model::SceneDecoder::forward), same result.
  primitives::ScenePrimitives decode(const SceneInput& input, bool streaming = false);
  // Streaming decode whose primitives are built a latent frame at a time and
  // moved to `out_device` as they come (e.g. the CPU), so the decoding memory
  // on the model's device stays bounded whatever the number of latent frames.
  // Same triangles as decode(input, true); no autograd graph is kept.
  primitives::ScenePrimitives decode_to(const SceneInput& input, const at::Device& out_device);
  // Renders one scene (no batch dimension) into cams, after pruning by the
  // config's prune_opacity, with the rasterizer of its representation.
  RenderedViews render(const primitives::ScenePrimitives& scene, const camera::Cameras& cams, int64_t height,
                       int64_t width) const;
  // The same, pruning below `min_opacity` instead (training's prune warm-up).
  RenderedViews render(const primitives::ScenePrimitives& scene, const camera::Cameras& cams, int64_t height,
                       int64_t width, double min_opacity) const;

  const PipelineConfig& config() const { return config_; }
  model::SceneDecoder& decoder() { return decoder_; }
  // triangles.opacity_shift from now on (the trainer's opacity calibration at
  // the start of a pruning stage, train/opacity_calibration.h).
  void set_opacity_shift(double shift) { config_.triangles.opacity_shift = shift; }

 private:
  PipelineConfig config_;
  model::SceneDecoder decoder_;
};

}  // namespace flat::pipeline
