// rasterize_surfels(): input checks, dtype/device dispatch and the autograd
// Function with the analytic backward (CPU reference or CUDA kernels).
#include "flat/surfels/rasterize_surfels.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "surfels/cpu/raster_surfels_cpu.h"
#if FLAT_WITH_CUDA
#include "surfels/cuda/raster_surfels_cuda.h"
#endif

namespace flat::surfels {

static_assert(kDistortionNear == kNdcNear && kDistortionFar == kNdcFar,
              "the kernels' NDC range is the header's");

namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

RasterConstants to_constants(const render::RasterSettings& s) {
  RasterConstants k;
  k.near_plane = (float)s.near_plane;
  k.alpha_max = (float)s.alpha_max;
  k.alpha_min = (float)s.alpha_min;
  k.t_min = (float)s.transmittance_min;
  return k;
}

struct RasterizeSurfelsFunction : public torch::autograd::Function<RasterizeSurfelsFunction> {
  static variable_list forward(AutogradContext* ctx, const at::Tensor& means, const at::Tensor& scales,
                               const at::Tensor& rotations, const at::Tensor& colors, const at::Tensor& opacities,
                               const at::Tensor& w2c, const at::Tensor& K, const at::Tensor& background,
                               int64_t height, int64_t width, double near_plane, double alpha_max, double alpha_min,
                               double t_min) {
    SurfelInputs in{means, scales, rotations, colors, opacities, w2c, K, background, height, width, {}};
    in.k.near_plane = (float)near_plane;
    in.k.alpha_max = (float)alpha_max;
    in.k.alpha_min = (float)alpha_min;
    in.k.t_min = (float)t_min;
    SurfelOutputs out;
    if (means.is_cuda()) {
#if FLAT_WITH_CUDA
      std::vector<at::Tensor> views;
      const bool for_backward = means.requires_grad() || scales.requires_grad() || rotations.requires_grad() ||
                                colors.requires_grad() || opacities.requires_grad();
      out = cuda::forward(in, for_backward, views);
      ctx->saved_data["views"] = views;
#else
      fail("rasterize_surfels: tensors are on CUDA but this build has no CUDA kernels (FLAT_WITH_CUDA=OFF)");
#endif
    } else {
      out = cpu::forward(in);
    }
    ctx->save_for_backward({means, scales, rotations, colors, opacities, w2c, K, background});
    ctx->saved_data["H"] = height;
    ctx->saved_data["W"] = width;
    ctx->saved_data["near"] = near_plane;
    ctx->saved_data["alpha_max"] = alpha_max;
    ctx->saved_data["alpha_min"] = alpha_min;
    ctx->saved_data["t_min"] = t_min;
    ctx->mark_non_differentiable({out.median_depth, out.max_weight});
    return {out.rgb, out.alpha, out.depth, out.normal, out.median_depth, out.max_weight, out.distortion};
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    SurfelInputs in{saved[0], saved[1], saved[2], saved[3], saved[4], saved[5], saved[6], saved[7],
                    ctx->saved_data["H"].toInt(), ctx->saved_data["W"].toInt(), {}};
    in.k.near_plane = (float)ctx->saved_data["near"].toDouble();
    in.k.alpha_max = (float)ctx->saved_data["alpha_max"].toDouble();
    in.k.alpha_min = (float)ctx->saved_data["alpha_min"].toDouble();
    in.k.t_min = (float)ctx->saved_data["t_min"].toDouble();
    const int64_t V = in.w2c.size(0), H = in.height, W = in.width;
    const auto opts = in.means.options();
    auto grad_or_zero = [&](const at::Tensor& g, int64_t C) {
      return g.defined() ? g.to(opts).contiguous() : at::zeros({V, C, H, W}, opts);
    };
    const SurfelOutputGrads up{grad_or_zero(grads[0], 3), grad_or_zero(grads[1], 1), grad_or_zero(grads[2], 1),
                               grad_or_zero(grads[3], 3), grad_or_zero(grads[6], 1)};
    SurfelGrads g;
    if (in.means.is_cuda()) {
#if FLAT_WITH_CUDA
      const auto views = ctx->saved_data["views"].toTensorVector();
      // No state was kept when no scene input required grad: nothing to compute.
      if (views.empty()) return variable_list(14);
      g = cuda::backward(in, views, up);
#endif
    } else {
      g = cpu::backward(in, up);
    }
    variable_list out(14);
    out[0] = g.means;
    out[1] = g.scales;
    out[2] = g.rotations;
    out[3] = g.colors;
    out[4] = g.opacities;
    return out;
  }
};

void check_inputs(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                  const at::Tensor& colors, const at::Tensor& opacities, const camera::Cameras& cams, int64_t height,
                  int64_t width) {
  // "rasterize_surfels: scales must be (N,2) with N = 5, got (5,3)"
  auto check = [](const at::Tensor& t, const std::vector<int64_t>& expected, const std::string& name,
                  const std::string& layout) {
    bool ok = t.defined() && t.dim() == (int64_t)expected.size();
    for (size_t i = 0; ok && i < expected.size(); ++i) ok = expected[i] < 0 || t.size(i) == expected[i];
    FLAT_CHECK(ok, "rasterize_surfels: " + name + " must be " + layout + ", got " + shape_str(t));
  };
  check(means, {-1, 3}, "means", "(N,3)");
  const int64_t N = means.size(0);
  const std::string n = " with N = " + std::to_string(N);
  check(scales, {N, 2}, "scales", "(N,2)" + n);
  check(rotations, {N, 4}, "rotations", "(N,4) quaternions (w,x,y,z)" + n);
  check(colors, {N, 3}, "colors", "(N,3)" + n);
  check(opacities, {N}, "opacities", "(N)" + n);
  cams.check("rasterize_surfels: cameras");
  FLAT_CHECK(height > 0 && width > 0, "rasterize_surfels: image size must be positive, got " +
                                          std::to_string(height) + "x" + std::to_string(width));
  FLAT_CHECK(height * width <= (int64_t(1) << 30), "rasterize_surfels: image too large (" + std::to_string(height) +
                                                       "x" + std::to_string(width) + ")");
  for (const auto* t : {&means, &scales, &rotations, &colors, &opacities})
    FLAT_CHECK(t->is_floating_point(), "rasterize_surfels: inputs must be floating point, got " +
                                           std::string(c10::toString(t->scalar_type())));
  const auto dev = means.device();
  for (const auto* t : {&scales, &rotations, &colors, &opacities})
    FLAT_CHECK(t->device() == dev, "rasterize_surfels: means, scales, rotations, colors and opacities must be on one device");
  FLAT_CHECK(dev.is_cpu() || dev.is_cuda(), "rasterize_surfels: unsupported device " + dev.str());
}

// Finite values, opacities in [0, 1], scales > 0, non-zero quaternions: one
// reduction each, read with one host copy (a sync on the GPU).
void check_values(const SurfelInputs& in) {
  if (in.means.size(0) == 0) return;
  const at::Tensor stats =
      at::stack({(in.means.sum() + in.scales.sum() + in.rotations.sum() + in.colors.sum() + in.opacities.sum())
                     .to(at::kDouble),
                 in.opacities.min().to(at::kDouble), in.opacities.max().to(at::kDouble),
                 in.scales.min().to(at::kDouble), in.rotations.square().sum(1).min().to(at::kDouble)})
          .cpu();
  const double* s = stats.data_ptr<double>();
  if (!std::isfinite(s[0])) {
    check_finite(in.means, "rasterize_surfels: means");
    check_finite(in.scales, "rasterize_surfels: scales");
    check_finite(in.rotations, "rasterize_surfels: rotations");
    check_finite(in.colors, "rasterize_surfels: colors");
    check_finite(in.opacities, "rasterize_surfels: opacities");
  }
  FLAT_CHECK(s[1] >= 0.0 && s[2] <= 1.0, "rasterize_surfels: opacities must lie in [0, 1], got range [" +
                                             std::to_string(s[1]) + ", " + std::to_string(s[2]) + "]");
  FLAT_CHECK(s[3] > 0.0, "rasterize_surfels: scales must be > 0, got min " + std::to_string(s[3]));
  FLAT_CHECK(s[4] > 0.0, "rasterize_surfels: rotations must be non-zero quaternions (w,x,y,z), got one of norm 0");
}

}  // namespace

render::RenderOutput rasterize_surfels(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                                       const at::Tensor& colors, const at::Tensor& opacities,
                                       const camera::Cameras& cams, int64_t height, int64_t width,
                                       const render::RasterSettings& settings) {
  settings.check();
  // The cameras on the host (a few hundred bytes): both back ends read them there.
  const camera::Cameras host_cams = cams.to(at::kCPU);
  check_inputs(means, scales, rotations, colors, opacities, host_cams, height, width);
  const auto dev = means.device();
  // fp32 maths, except the double CPU reference used for finite differences.
  const bool use_double = dev.is_cpu() && means.scalar_type() == at::kDouble;
  const auto opts = at::TensorOptions().device(dev).dtype(use_double ? at::kDouble : at::kFloat);
  auto prep = [&](const at::Tensor& t) { return t.to(opts).contiguous(); };
  SurfelInputs in;
  in.means = prep(means);
  in.scales = prep(scales);
  in.rotations = prep(rotations);
  in.colors = prep(colors);
  in.opacities = prep(opacities);
  const auto host = opts.device(at::kCPU);
  in.w2c = camera::world_to_camera(host_cams.c2w.to(host).to(at::kDouble)).to(host).contiguous();
  in.K = camera::pixel_intrinsics(host_cams.intrinsics.to(host), height, width).contiguous();
  in.background = at::tensor(settings.background, at::TensorOptions().dtype(at::kDouble)).to(host);
  in.height = height;
  in.width = width;
  in.k = to_constants(settings);
  check_values(in);
  auto outs = RasterizeSurfelsFunction::apply(in.means, in.scales, in.rotations, in.colors, in.opacities, in.w2c,
                                              in.K, in.background, height, width, (double)in.k.near_plane,
                                              (double)in.k.alpha_max, (double)in.k.alpha_min, (double)in.k.t_min);
  render::RenderOutput r;
  r.rgb = outs[0];
  r.alpha = outs[1];
  r.depth = outs[2];
  r.normal = outs[3];
  r.median_depth = outs[4];
  r.max_weight = outs[5];
  r.distortion = outs[6];
  return r;
}

}  // namespace flat::surfels
