// The training objective (paper, Losses):
//   L = l_rgb L2 + l_perc LPIPS + l_D L_D + l_N L_N + l_O L_O
//       (+ l_nc normal consistency + l_dist depth distortion, 2DGS baseline)
// with the paper's weights 1.0, 0.5, 0.01, 0.01, 0.001 as defaults (the opacity
// term belongs to the high-resolution stage: stage configs set it to 0 before).
// A term with weight 0 is not computed. A term with weight > 0 whose inputs are
// missing is an error naming the input.
#pragma once
#include <map>
#include <string>

#include <ATen/ATen.h>

#include "flat/core/config.h"
#include "flat/loss/lpips.h"

namespace flat::loss {

struct LossConfig {
  double lambda_rgb = 1.0;
  double lambda_perc = 0.5;
  double lambda_depth = 0.01;
  double lambda_normal = 0.01;
  // A depth or normal term whose training scenes carry no depth / normals trains
  // nothing: "fail" refuses to start, "warn" only says so (train/geometry_targets.h).
  std::string missing_geometry = "fail";
  double lambda_opacity = 0.001;
  double lambda_normal_consistency = 0.0;  // 2DGS regulariser
  double lambda_distortion = 0.0;          // 2DGS regulariser
  std::string lpips_weights;               // safetensors file, see docs/losses.md
  int64_t lpips_max_size = 512;            // longer side before LPIPS (0 = never resize)
  int64_t lpips_chunk = 4;                 // views per LPIPS pass
  bool lpips_checkpoint = true;            // recompute each pass's VGG activations in backward
  std::string lpips_precision = "auto";    // auto (bf16 in a bf16 run on CUDA) | fp32 | bf16
  std::string depth_target = "depth";      // the target map holds "depth" or "disparity"
  double normal_alpha_threshold = 0.5;     // M = alpha > threshold
  bool random_background = false;          // training renders over a colour drawn per view (train/random_background.h)

  template <class V>
  void visit(V& v) {
    v.field("lambda_rgb", lambda_rgb, config::non_negative(), "weight of the L2 photometric loss");
    v.field("lambda_perc", lambda_perc, config::non_negative(), "weight of LPIPS (needs lpips_weights)");
    v.field("lambda_depth", lambda_depth, config::non_negative(), "weight of the scale-invariant disparity loss");
    v.field("lambda_normal", lambda_normal, config::non_negative(), "weight of the normal loss");
    v.field("missing_geometry", missing_geometry, config::one_of({"fail", "warn"}),
            "fail | warn: when lambda_depth or lambda_normal is set and no training scene has depth / normals");
    v.field("lambda_opacity", lambda_opacity, config::non_negative(), "weight of the L1 opacity regulariser");
    v.field("lambda_normal_consistency", lambda_normal_consistency, config::non_negative(),
            "weight of the 2DGS normal-consistency regulariser");
    v.field("lambda_distortion", lambda_distortion, config::non_negative(),
            "weight of the 2DGS depth-distortion regulariser");
    v.field("lpips_weights", lpips_weights, "LPIPS VGG safetensors file");
    v.field("lpips_max_size", lpips_max_size, config::non_negative(), "resize longer side to this before LPIPS");
    v.field("lpips_chunk", lpips_chunk, config::positive(), "views per LPIPS pass through VGG");
    v.field("lpips_checkpoint", lpips_checkpoint,
            "free each LPIPS pass's VGG activations and recompute them in backward (memory of one pass; "
            "false: faster, keeps every pass's activations)");
    v.field("lpips_precision", lpips_precision, config::one_of({"auto", "fp32", "bf16"}),
            "LPIPS convolution dtype: auto = bf16 when the run computes in bf16 on CUDA, else fp32");
    v.field("depth_target", depth_target, config::one_of({"depth", "disparity"}), "what the target depth map holds");
    v.field("normal_alpha_threshold", normal_alpha_threshold, config::range(0.0, 1.0),
            "normal loss mask: alpha above this");
    v.field("random_background", random_background,
            "training renders composite over a colour drawn per view and step instead of pipeline.raster.background "
            "(validation and evaluation keep it): transparency cannot stand in for a dark surface");
  }
};

// Plain tensors from the renderer and the dataset (no dependency on flat_render).
struct LossInputs {
  at::Tensor rgb, target_rgb;         // (V,3,H,W) in [0,1]
  at::Tensor alpha;                   // (V,1,H,W)
  at::Tensor depth, target_depth;     // (V,1,H,W); target <= 0 or non-finite = invalid
  at::Tensor normal, target_normal;   // (V,3,H,W), camera space
  at::Tensor opacities;               // (N) or (B,N)
  at::Tensor intrinsics;              // (V,4) normalised, for normal consistency
  at::Tensor distortion;              // (V,1,H,W) rasterizer distortion map
};

struct LossResult {
  at::Tensor total;                          // scalar, differentiable
  std::map<std::string, at::Tensor> terms;   // unweighted terms, detached: "rgb", "lpips", ...
};

class Objective {
 public:
  // Validates the config; with lambda_perc > 0 loads the LPIPS weights and
  // throws flat::Error (naming the file and tensor) when they are missing or
  // wrong: training never starts silently without its perceptual loss.
  // bf16_run: the run computes in bf16 (lpips_precision auto follows it on CUDA).
  explicit Objective(LossConfig cfg, const at::Device& device = at::kCPU, bool bf16_run = false);
  LossResult operator()(const LossInputs& in);
  const LossConfig& config() const { return cfg_; }
  // The loaded LPIPS network (empty holder when lambda_perc is 0), for metrics.
  Lpips lpips_network() const { return lpips_; }
  // How the loss runs LPIPS (from the lpips_* keys and the run's precision).
  const LpipsOptions& lpips_options() const { return lpips_options_; }

 private:
  LossConfig cfg_;
  Lpips lpips_{nullptr};
  LpipsOptions lpips_options_;
};

}  // namespace flat::loss
