// rasterize_gaussians(): input checks, dtype/device dispatch and the autograd
// Function with the analytic backward (CPU reference or CUDA kernels).
#include "flat/gaussians/rasterize_gaussians.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "gaussians/cpu/raster_gaussians_cpu.h"
#if FLAT_WITH_CUDA
#include "gaussians/cuda/raster_gaussians_cuda.h"
#endif

namespace flat::gaussians {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

GaussianConstants to_constants(const render::RasterSettings& s) {
  GaussianConstants k;
  k.near_plane = (float)s.near_plane;
  k.alpha_max = (float)s.alpha_max;
  k.alpha_min = (float)s.alpha_min;
  k.t_min = (float)s.transmittance_min;
  return k;
}

void save_constants(AutogradContext* ctx, const GaussianConstants& k, int64_t H, int64_t W) {
  ctx->saved_data["near"] = (double)k.near_plane;
  ctx->saved_data["alpha_max"] = (double)k.alpha_max;
  ctx->saved_data["alpha_min"] = (double)k.alpha_min;
  ctx->saved_data["t_min"] = (double)k.t_min;
  ctx->saved_data["H"] = H;
  ctx->saved_data["W"] = W;
}

GaussianConstants load_constants(AutogradContext* ctx) {
  GaussianConstants k;
  k.near_plane = (float)ctx->saved_data["near"].toDouble();
  k.alpha_max = (float)ctx->saved_data["alpha_max"].toDouble();
  k.alpha_min = (float)ctx->saved_data["alpha_min"].toDouble();
  k.t_min = (float)ctx->saved_data["t_min"].toDouble();
  return k;
}

struct RasterizeGaussiansFunction : public torch::autograd::Function<RasterizeGaussiansFunction> {
  static variable_list forward(AutogradContext* ctx, const at::Tensor& means, const at::Tensor& scales,
                               const at::Tensor& rotations, const at::Tensor& colors, const at::Tensor& opacities,
                               const at::Tensor& w2c, const at::Tensor& K, const at::Tensor& background,
                               const at::Tensor& value_stats, int64_t height, int64_t width, GaussianConstants k) {
    GaussianInputs in{means, scales, rotations, colors, opacities, w2c, K, background, height, width, k, value_stats};
    GaussianOutputs out;
    if (means.is_cuda()) {
#if FLAT_WITH_CUDA
      std::vector<at::Tensor> views;
      const bool for_backward = means.requires_grad() || scales.requires_grad() || rotations.requires_grad() ||
                                colors.requires_grad() || opacities.requires_grad();
      out = cuda::forward(in, for_backward, views);
      ctx->saved_data["views"] = views;
#else
      fail("rasterize_gaussians: tensors are on CUDA but this build has no CUDA kernels (FLAT_WITH_CUDA=OFF)");
#endif
    } else {
      out = cpu::forward(in);
    }
    ctx->save_for_backward({means, scales, rotations, colors, opacities, w2c, K, background});
    save_constants(ctx, k, height, width);
    ctx->mark_non_differentiable({out.median_depth, out.max_weight});
    return {out.rgb, out.alpha, out.depth, out.median_depth, out.max_weight};
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    GaussianInputs in{saved[0],
                      saved[1],
                      saved[2],
                      saved[3],
                      saved[4],
                      saved[5],
                      saved[6],
                      saved[7],
                      ctx->saved_data["H"].toInt(),
                      ctx->saved_data["W"].toInt(),
                      load_constants(ctx),
                      at::Tensor()};
    const int64_t V = in.w2c.size(0), H = in.height, W = in.width;
    const auto opts = in.means.options();
    auto grad_or_zero = [&](const at::Tensor& g, int64_t C) {
      return g.defined() ? g.to(opts).contiguous() : at::zeros({V, C, H, W}, opts);
    };
    const at::Tensor g_rgb = grad_or_zero(grads[0], 3), g_alpha = grad_or_zero(grads[1], 1);
    const at::Tensor g_depth = grad_or_zero(grads[2], 1);
    GaussianGrads g;
    if (in.means.is_cuda()) {
#if FLAT_WITH_CUDA
      const auto views = ctx->saved_data["views"].toTensorVector();
      // No state was kept when no scene input required grad: nothing to compute.
      if (views.empty()) return variable_list(12);
      g = cuda::backward(in, views, g_rgb, g_alpha, g_depth);
#endif
    } else {
      g = cpu::backward(in, g_rgb, g_alpha, g_depth);
    }
    return {g.means,      g.scales,     g.rotations,  g.colors,     g.opacities,  at::Tensor(),
            at::Tensor(), at::Tensor(), at::Tensor(), at::Tensor(), at::Tensor(), at::Tensor()};
  }
};

void check_inputs(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                  const at::Tensor& colors, const at::Tensor& opacities, const camera::Cameras& cams, int64_t height,
                  int64_t width) {
  check_shape(means, {-1, 3}, "rasterize_gaussians: means", "(N,3)");
  const int64_t N = means.size(0);
  const std::string n = " with N = " + std::to_string(N);
  check_shape(scales, {N, 3}, "rasterize_gaussians: scales", "(N,3)" + n);
  check_shape(rotations, {N, 4}, "rasterize_gaussians: rotations", "(N,4)" + n);
  check_shape(colors, {N, 3}, "rasterize_gaussians: colors", "(N,3)" + n);
  check_shape(opacities, {N}, "rasterize_gaussians: opacities", "(N)" + n);
  cams.check("rasterize_gaussians: cameras");
  FLAT_CHECK(height > 0 && width > 0, "rasterize_gaussians: image size must be positive, got " +
                                          std::to_string(height) + "x" + std::to_string(width));
  FLAT_CHECK(height * width <= (int64_t(1) << 30),
             "rasterize_gaussians: image too large (" + std::to_string(height) + "x" + std::to_string(width) + ")");
  for (const auto* t : {&means, &scales, &rotations, &colors, &opacities})
    FLAT_CHECK(t->is_floating_point(), "rasterize_gaussians: inputs must be floating point, got " +
                                           std::string(c10::toString(t->scalar_type())));
  const auto dev = means.device();
  for (const auto* t : {&scales, &rotations, &colors, &opacities})
    FLAT_CHECK(t->device() == dev,
               "rasterize_gaussians: means, scales, rotations, colors and opacities must be on one device");
  FLAT_CHECK(dev.is_cpu() || dev.is_cuda(), "rasterize_gaussians: unsupported device " + dev.str());
}

// The value checks' statistics: [sum of every input value, min and max
// opacity, min scale, min quaternion norm^2]. On the GPU they are copied to
// pinned host memory without a sync; the CUDA back end checks them at its
// first wait for the device.
at::Tensor value_stats(const GaussianInputs& in) {
  const at::Tensor sum = in.means.sum() + in.scales.sum() + in.rotations.sum() + in.colors.sum() + in.opacities.sum();
  const at::Tensor stats =
      at::stack({sum.to(at::kDouble), in.opacities.min().to(at::kDouble), in.opacities.max().to(at::kDouble),
                 in.scales.min().to(at::kDouble), in.rotations.square().sum(1).min().to(at::kDouble)});
  if (!stats.is_cuda()) return stats;
  at::Tensor host = at::empty({5}, at::TensorOptions().dtype(at::kDouble).pinned_memory(true));
  host.copy_(stats, /*non_blocking=*/true);
  return host;
}

}  // namespace

void check_input_values(const GaussianInputs& in) {
  if (in.value_stats.numel() == 0) return;  // no Gaussians: nothing to check
  const double* s = in.value_stats.data_ptr<double>();
  if (!std::isfinite(s[0])) {
    check_finite(in.means, "rasterize_gaussians: means");
    check_finite(in.scales, "rasterize_gaussians: scales");
    check_finite(in.rotations, "rasterize_gaussians: rotations");
    check_finite(in.colors, "rasterize_gaussians: colors");
    check_finite(in.opacities, "rasterize_gaussians: opacities");
  }
  FLAT_CHECK(s[1] >= 0.0 && s[2] <= 1.0, "rasterize_gaussians: opacities must lie in [0, 1], got range [" +
                                             std::to_string(s[1]) + ", " + std::to_string(s[2]) + "]");
  FLAT_CHECK(s[3] > 0.0, "rasterize_gaussians: scales must be > 0, got min " + std::to_string(s[3]));
  FLAT_CHECK(s[4] > 0.0, "rasterize_gaussians: rotations must be non-zero quaternions (w,x,y,z)");
}

render::RenderOutput rasterize_gaussians(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
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
  GaussianInputs in;
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
  in.value_stats = in.means.size(0) > 0 ? value_stats(in) : at::empty({0}, at::kDouble);
  if (!dev.is_cuda()) check_input_values(in);  // else at the CUDA back end's first sync
  auto outs = RasterizeGaussiansFunction::apply(in.means, in.scales, in.rotations, in.colors, in.opacities, in.w2c,
                                                in.K, in.background, in.value_stats, height, width, in.k);
  render::RenderOutput r;
  r.rgb = outs[0];
  r.alpha = outs[1];
  r.depth = outs[2];
  r.median_depth = outs[3];
  r.max_weight = outs[4];
  return r;  // normal and distortion stay undefined
}

}  // namespace flat::gaussians
