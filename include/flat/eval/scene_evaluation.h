// Scoring one scene as the paper's Table 1 does (Evaluation; "Novel View
// Synthesis and Geometry Quality"): decode the scene's latent window, render
// the evaluation views, and compare with the scene's frames:
//   PSNR, SSIM, LPIPS per view (averaged over the scene's views);
//   normal L1 and cosine against the scene's reference normals, only where
//   the render's alpha > 0.5 and a reference normal exists, averaged over
//   those pixels of all views;
//   depth (depth_metrics.h), where the scene has reference depth, with the
//   same alpha mask: the SI-log error per view, averaged over the views, and
//   the planar roughness over the planar pixels of all views.
// Views: "scene" = every frame of the scene (seen and unseen by the window),
// "window" = the window's own frames, "unseen" = the frames outside it; more
// than max_views are subsampled evenly (the same frames every time).
#pragma once
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include <ATen/ATen.h>

#include "flat/data/scene.h"
#include "flat/eval/baselines.h"
#include "flat/eval/image_metrics.h"
#include "flat/loss/lpips.h"
#include "flat/pipeline/scene_pipeline.h"

namespace flat::eval {

struct EvalSettings {
  std::string views = "scene";  // scene | window | unseen
  int64_t max_views = 0;        // 0 = all
  int64_t window = 0;           // which latent window decodes the scene
  std::string latent_set;       // which latent set ("176x320_f17"; "" = each scene's only one)
  int64_t height = 0, width = 0;  // 0 = the latents' frame size
  SsimConvention ssim = SsimConvention::skimage;
  double normal_alpha = 0.5;    // normals scored where alpha > this
  bool streaming = true;
  bool bf16 = false;            // CUDA autocast while decoding and rendering
  int64_t render_chunk = 8;
  std::string fingerprint() const;  // what makes two runs' scores comparable
};

struct SceneScore {
  std::string dataset, scene, dir;
  bool ok = false;
  std::string error;  // why it failed (ok = false)
  int64_t views = 0, unseen_views = 0, triangles = 0;
  double psnr = NAN, ssim = NAN, lpips = NAN;
  double normal_l1 = NAN, normal_cosine = NAN;
  int64_t normal_pixels = 0;
  // Depth (depth_metrics.h); NaN without reference depth.
  double depth_si_log = NAN, planar_roughness = NAN;
  int64_t planar_pixels = 0;
  // Baselines on the same views (baselines.h): PSNR of the mean-colour
  // oracle, of the other scenes' mean image, and of these renders against
  // the ground truth of `swap_scene` (NaN where not measured).
  double mean_colour_psnr = NAN, dataset_mean_psnr = NAN, swap_psnr = NAN;
  std::string swap_scene;
  std::string latent_encoder;  // "pretrained" | "random": how the scene's latents were made
  double seconds = 0;
};

// What the baselines need from the rest of the dataset (either may be null).
struct BaselineInputs {
  const data::Scene* swap_with = nullptr;  // the scene whose frames the renders are swapped against
  const FrameSums* frame_sums = nullptr;   // the dataset's frames by index, this scene's included
};

// The frames scored for `scene`, fitted to the evaluation size, added to `sums`.
void add_frame_sums(FrameSums& sums, const data::Scene& scene, const EvalSettings& settings);

// Frame indices of the evaluation views (throws when there are none).
std::vector<int64_t> evaluation_views(const data::Scene& scene, const EvalSettings& settings);

// The decoder's input for latent window `window` of the scene (its chosen
// latent set): latents and the window's cameras, B = 1, float32, on the CPU.
pipeline::SceneInput window_input(const data::Scene& scene, int64_t window, const std::string& camera_rays);

// lpips: an empty holder leaves LPIPS NaN. Throws flat::Error on a bad scene
// (the caller records it as a failure).
SceneScore evaluate_scene(pipeline::ScenePipeline& pipeline, const data::Scene& scene, const EvalSettings& settings,
                          loss::Lpips lpips, const BaselineInputs& baselines = {});

}  // namespace flat::eval
