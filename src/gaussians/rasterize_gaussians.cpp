// rasterize_gaussians(): input checks, dtype/device dispatch and the autograd
// Function with the analytic backward (CPU reference or CUDA kernels).
#include "flat/gaussians/rasterize_gaussians.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "gaussians/cpu/raster_gaussians_cpu.h"
#include "flat/render/shared/raster_dispatch.h"
#if FLAT_WITH_CUDA
#include "gaussians/cuda/raster_gaussians_cuda.h"
#endif

namespace flat::gaussians {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

struct RasterizeGaussiansFunction : public torch::autograd::Function<RasterizeGaussiansFunction> {
  static variable_list forward(AutogradContext* ctx, const at::Tensor& means, const at::Tensor& scales,
                               const at::Tensor& rotations, const at::Tensor& colors, const at::Tensor& opacities,
                               const at::Tensor& w2c, const at::Tensor& K, const at::Tensor& background,
                               const at::Tensor& value_stats, int64_t height, int64_t width, CompositingConstants k) {
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
    render::save_constants(ctx, k, height, width);
    ctx->mark_non_differentiable({out.median_depth, out.max_weight});
    return {out.rgb, out.alpha, out.depth, out.median_depth, out.max_weight};
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto c = render::load_constants<CompositingConstants>(ctx);
    GaussianInputs in{saved[0], saved[1], saved[2], saved[3], saved[4], saved[5], saved[6], saved[7],
                      c.height, c.width, c.k, at::Tensor()};
    const int64_t V = in.w2c.size(0), H = in.height, W = in.width;
    const auto opts = in.means.options();
    const at::Tensor g_rgb = render::grad_or_zero(grads[0], opts, V, 3, H, W);
    const at::Tensor g_alpha = render::grad_or_zero(grads[1], opts, V, 1, H, W);
    const at::Tensor g_depth = render::grad_or_zero(grads[2], opts, V, 1, H, W);
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
  render::check_common_inputs("rasterize_gaussians", {means, scales, rotations, colors, opacities},
                              "means, scales, rotations, colors and opacities", cams, height, width);
}

}  // namespace

void check_input_values(const GaussianInputs& in) {
  if (in.value_stats.numel() == 0) return;  // no Gaussians: nothing to check
  render::check_input_stats(in.value_stats.data_ptr<double>(), "rasterize_gaussians",
                            {in.means, in.scales, in.rotations, in.colors, in.opacities},
                            {"means", "scales", "rotations", "colors", "opacities"}, "scales", true);
}

render::RenderOutput rasterize_gaussians(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                                         const at::Tensor& colors, const at::Tensor& opacities,
                                         const camera::Cameras& cams, int64_t height, int64_t width,
                                         const render::CompositingSettings& settings) {
  settings.check();
  const camera::Cameras host_cams = cams.to(at::kCPU);  // both back ends read them there
  check_inputs(means, scales, rotations, colors, opacities, host_cams, height, width);
  const auto dev = means.device();
  const auto opts = render::compute_options(means);
  auto prep = [&](const at::Tensor& t) { return t.to(opts).contiguous(); };
  GaussianInputs in;
  in.means = prep(means);
  in.scales = prep(scales);
  in.rotations = prep(rotations);
  in.colors = prep(colors);
  in.opacities = prep(opacities);
  const render::HostViews views = render::host_views(host_cams, height, width, settings, opts);
  in.w2c = views.w2c;
  in.K = views.K;
  in.background = views.background;
  in.height = height;
  in.width = width;
  in.k = settings.constants();
  // The value checks' statistics: on the GPU copied to the host without a
  // sync, checked at the CUDA back end's first wait for the device.
  in.value_stats = in.means.size(0) > 0 ? render::to_host_async(render::input_stats(
                                              {in.means, in.scales, in.rotations, in.colors, in.opacities},
                                              in.opacities, in.scales, in.rotations))
                                        : at::empty({0}, at::kDouble);
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
