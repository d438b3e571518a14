// Ray-centred triangles (paper, Method, "Decoding Triangles"): one triangle
// per decoder token, i.e. per 2x2 pixel block of each frame, placed on the
// block's anchor ray and shaped / oriented in a frame aligned with that ray.
// The maths (with equations) is in src/primitives/ray_triangles.cpp;
// docs/primitives.md explains the choices. The raw channel order is in
// triangle_channels.h.
#pragma once
#include <cstdint>
#include <string>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"
#include "flat/core/config.h"
#include "flat/primitives/head_channels.h"
#include "flat/primitives/triangle_soup.h"

namespace flat::primitives {

struct TriangleParamConfig {
  // "ray_centred" (the paper), or the ablations of the paper's Table (ablation):
  // "three_offsets" (free vertex offsets, residual rotation) and
  // "global_rotation" (Cholesky shape, world-space quaternion).
  std::string parameterisation = "ray_centred";

  // Depth along the anchor ray (metres); x = raw depth channel.
  //  "sigmoid":  D = near (1 - w) + far w,  w = sigmoid(x - depth_shift)   (Lyra)
  //  "exp":      D = near + (depth_init - near) exp(x)
  //  "softplus": D = near + softplus(x + b), b chosen so that D(0) = depth_init
  std::string depth_activation = "sigmoid";
  double depth_near = 0.1;
  double depth_far = 500.0;
  double depth_shift = 1.65;
  double depth_init = 2.0;

  // Size at initialisation: the canonical triangle's inradius, projected into
  // its own camera, is init_scale * sqrt(2) pixels (full resolution), i.e. the
  // triangle circumscribes the circle through the 4 corners of its 2x2 block.
  double init_scale = 1.0;
  // L00, L11 = shape_min + softplus(x + b) with b so that L(0) = 1: strictly
  // positive (>= shape_min) whatever the network outputs. L10 = x (shear).
  double shape_min = 0.05;

  // Residual rotation: tilt = max_tilt tanh(x) (radians, keeps the triangle
  // from turning edge-on to its ray), spin = x.
  double max_tilt = 1.3;

  // "sigmoid": c = sigmoid(x); "tanh": c = 0.5 tanh(x) + 0.5 (Lyra);
  // "sh": raw SH coefficients (B,N,K,3), evaluated by the renderer.
  std::string colour_activation = "sigmoid";
  int64_t sh_degree = 0;  // only with colour_activation "sh"

  // opacity = sigmoid(x - opacity_shift)
  double opacity_shift = 0.0;

  // "softplus": sigma = sigma_min + softplus(x + b), sigma(0) = sigma_init;
  // "exp":      sigma = sigma_min + (sigma_init - sigma_min) exp(x).
  std::string sigma_activation = "softplus";
  double sigma_min = 0.01;
  double sigma_init = 1.0;

  template <class V>
  void visit(V& v) {
    v.field("parameterisation", parameterisation,
            config::one_of({"ray_centred", "three_offsets", "global_rotation"}), "triangle parameterisation");
    v.field("depth_activation", depth_activation, config::one_of({"sigmoid", "exp", "softplus"}),
            "depth activation");
    v.field("depth_near", depth_near, config::positive(), "smallest depth (m)");
    v.field("depth_far", depth_far, config::positive(), "largest depth of the sigmoid activation (m)");
    v.field("depth_shift", depth_shift, "sigmoid activation: w = sigmoid(x - shift)");
    v.field("depth_init", depth_init, config::positive(), "exp/softplus activation: depth at x = 0 (m)");
    v.field("init_scale", init_scale, config::positive(), "inradius at init, in units of sqrt(2) pixels");
    v.field("shape_min", shape_min, config::positive(), "lower bound of L00, L11");
    v.field("max_tilt", max_tilt, config::range(0.0, 1.5707963), "largest residual tilt (rad)");
    v.field("colour_activation", colour_activation, config::one_of({"sigmoid", "tanh", "sh"}),
            "colour activation");
    v.field("sh_degree", sh_degree, config::range(0, 3), "SH degree (colour_activation sh)");
    v.field("opacity_shift", opacity_shift, "opacity = sigmoid(x - shift)");
    v.field("sigma_activation", sigma_activation, config::one_of({"softplus", "exp"}), "sigma activation");
    v.field("sigma_min", sigma_min, config::non_negative(), "lower bound of sigma");
    v.field("sigma_init", sigma_init, config::positive(), "sigma at x = 0");
  }

  // Cross-field checks (depth_far > depth_near, sigma_init > sigma_min, ...);
  // throws flat::Error naming the fields.
  void check() const;
  // The raw channel layout this config expects.
  HeadChannels channels() const;
};

// raw: (B,C,T,H/2,W/2) head outputs, C = cfg.channels().total, any float dtype
// and device. cams: B*T cameras, frame-major per batch (camera b*T + t is frame
// t of scene b). image_height/width: the full-resolution image size (even).
// Returns the soup (B, N = T*H/2*W/2, ...) in float32 (float64 for float64
// input; half / bfloat16 heads are upcast); every op is ATen, so autograd
// differentiates it.
TriangleSoup build_triangles(const at::Tensor& raw, const camera::Cameras& cams, int64_t image_height,
                             int64_t image_width, const TriangleParamConfig& cfg);

}  // namespace flat::primitives
