// Differentiable triangle rasterizer (paper, Method: "Feedforward Triangle
// Splatting" and "Window Function"). Front-to-back alpha compositing of a
// world-space triangle soup into V cameras; see docs/rasterizer.md for every
// constant, the culling rule and the tolerances held between CPU and CUDA.
// The paper's equations live in flat/render/shared/triangle_math.h, shared by the CPU
// and CUDA passes: the product window (eq. "Window Function", window_forward /
// window_backward), the edge functions and the inradius-normalised distances.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"
#include "flat/core/config.h"
#include "flat/render/shared/compositing.h"

namespace flat::render {

// The settings every rasterizer composites with (triangles, and the 3DGS and
// 2DGS ones of gaussians:: and surfels::, which take these alone): the
// background, the near plane and the compositing rules. Defaults in
// flat/render/shared/compositing.h.
struct CompositingSettings {
  std::vector<double> background = {0.0, 0.0, 0.0};
  double near_plane = kDefaultNearPlane;    // metres; a primitive nearer is culled (triangles: any vertex)
  double alpha_max = kDefaultAlphaMax;      // alpha cap
  double alpha_min = kDefaultAlphaMin;      // fragments with smaller alpha are skipped
  double transmittance_min = kDefaultTransmittanceMin;  // a pixel stops before its transmittance drops below this

  template <class V>
  void visit(V& v) {
    v.field("background", background, config::range(0.0, 1.0), "background colour r,g,b in [0,1]");
    v.field("near_plane", near_plane, config::positive(), "cull primitives nearer than this (triangles: any vertex)");
    v.field("alpha_max", alpha_max, config::range(0.0, 0.999), "alpha cap");
    v.field("alpha_min", alpha_min, config::range(0.0, 1.0), "skip fragments with alpha below this");
    v.field("transmittance_min", transmittance_min, config::range(0.0, 0.999), "early-stop transmittance");
  }
  // Throws flat::Error on bad values (also when built in code, not from YAML):
  // the ranges declared in visit() (config::validate_fields), then the
  // cross-field rules.
  void check() const;
  // As the kernels read them (float).
  CompositingConstants constants() const;

 protected:
  // The rules between fields (background size, alpha_min below alpha_max).
  void check_relations() const;
};

// The triangle rasterizer's settings: the compositing ones and its window's
// and culling's. Only render::rasterize reads these extra fields.
struct RasterSettings : CompositingSettings {
  std::string window = "flat";  // "flat" (paper's product window) | "ts" (Triangle Splatting max-edge)
  double eps = 0.1;             // FLAT window: support extends eps * inradius beyond each edge
  double min_inradius = 1e-3;   // pixels; smaller (degenerate) triangles are culled
  double min_cos = 1e-3;        // edge-on cull: |cos(normal, ray to centroid)| below this
  // CUDA only, speed only (the images are the same): views binned by one
  // depth sort and one tile sort, and composited by one launch (1 or 2; 2
  // pays the sorts' host cost once for two views and holds two views' cull
  // scratch and one view's binning scratch more).
  int views_per_bin = 2;

  template <class V>
  void visit(V& v) {
    v.field("window", window, config::one_of({"flat", "ts"}), "window function: flat | ts");
    v.field("eps", eps, config::range(0.0, 1.0), "FLAT window support beyond each edge, in inradii");
    CompositingSettings::visit(v);
    v.field("min_inradius", min_inradius, config::non_negative(), "cull triangles with smaller screen inradius (px)");
    v.field("min_cos", min_cos, config::range(0.0, 1.0), "cull edge-on triangles below this |cos|");
    v.field("views_per_bin", views_per_bin, config::range(1, 2), "CUDA: views binned by one sort, 1 | 2 (speed only)");
  }
  void check() const;
};

struct RenderOutput {
  at::Tensor rgb;           // (V,3,H,W)  sum_k w_k c_k + T_final * background
  at::Tensor alpha;         // (V,1,H,W)  1 - T_final
  at::Tensor depth;         // (V,1,H,W)  sum_k w_k z_k(p): alpha-weighted, NOT divided by alpha
  at::Tensor normal;        // (V,3,H,W)  sum_k w_k n_k: camera space, facing the camera, alpha-weighted
  at::Tensor median_depth;  // (V,1,H,W)  depth where transmittance crosses 0.5 (no gradient)
  at::Tensor max_weight;    // (N,)       max blending weight over all pixels and views (no gradient)
  at::Tensor distortion;    // (V,1,H,W)  2DGS depth distortion (surfels::rasterize_surfels only; else undefined)
};

// vertices (N,3,3) world, colors (N,3), opacities (N) in [0,1], sigmas (N) > 0.
// Runs on the inputs' device: CPU -> reference, CUDA -> kernels. Float inputs
// are cast to float32 (gradients come back in the input dtype), except that
// all-double CPU inputs run the reference in double (for finite differences).
// Differentiable w.r.t. vertices, colors, opacities and sigmas.
RenderOutput rasterize(const at::Tensor& vertices, const at::Tensor& colors, const at::Tensor& opacities,
                       const at::Tensor& sigmas, const camera::Cameras& cams, int64_t height, int64_t width,
                       const RasterSettings& settings);

}  // namespace flat::render
