// Pixel-aligned 3DGS / 2DGS primitives (ray_gaussians.h has the equations).
#include "flat/primitives/ray_gaussians.h"

#include "flat/core/error.h"
#include "flat/primitives/head_channels.h"
#include "primitives/ray_anchors.h"

namespace flat::primitives {

GaussianSoup build_gaussians(const at::Tensor& raw, const camera::Cameras& cams, int64_t image_height,
                             int64_t image_width, const TriangleParamConfig& cfg, int64_t scale_count) {
  cfg.check();
  FLAT_CHECK(cfg.colour_activation != "sh",
             "build_gaussians: colour_activation 'sh' is for triangles only (use sigmoid or tanh)");
  const HeadChannels ch = gaussian_channels(scale_count);
  const RayAnchors a = ray_anchors(raw, ch.total, cams, image_height, image_width, "build_gaussians");
  auto group = [&](int64_t start, int64_t count) { return a.tokens.narrow(-1, start, count); };

  auto D = activate_depth(group(ch.depth, 1), cfg);  // (B,N,1)
  GaussianSoup g;
  g.means = (a.origins + D * a.directions).contiguous();
  auto footprint = cfg.init_scale * D * a.per_pixel.unsqueeze(-1);  // (B,N,1)
  g.scales = (footprint * shifted_softplus(group(ch.shape, scale_count), cfg.shape_min, 1.0)).contiguous();
  const auto opts = a.tokens.options();
  auto identity = at::tensor({1.0, 0.0, 0.0, 0.0}, opts.dtype(at::kDouble)).to(opts);
  auto q_local = group(ch.rotation, 4) + identity;
  q_local = q_local / q_local.norm(2, -1, true).clamp_min(1e-12);
  g.rotations = quaternion_multiply(matrix_to_quaternion(a.frames), q_local).contiguous();
  g.colors = activate_colour(group(ch.colour, 3), cfg).contiguous();
  g.opacities = at::sigmoid(group(ch.opacity, 1).squeeze(-1) - cfg.opacity_shift).contiguous();
  return g;
}

}  // namespace flat::primitives
