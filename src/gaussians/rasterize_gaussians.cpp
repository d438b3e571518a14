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

using Call = render::RasterCall<CompositingConstants>;

GaussianInputs inputs_of(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                         const at::Tensor& colors, const at::Tensor& opacities, const Call& c) {
  return {means,        scales,       rotations,          colors,   opacities, c.views.w2c,
          c.views.K,    c.views.background, c.height, c.width, c.k,     c.value_stats};
}

struct RasterizeGaussiansFunction : public torch::autograd::Function<RasterizeGaussiansFunction> {
  static variable_list forward(AutogradContext* ctx, const at::Tensor& means, const at::Tensor& scales,
                               const at::Tensor& rotations, const at::Tensor& colors, const at::Tensor& opacities,
                               const Call& call) {
    const GaussianInputs in = inputs_of(means, scales, rotations, colors, opacities, call);
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
    ctx->save_for_backward({means, scales, rotations, colors, opacities});
    render::save_call(ctx, call);
    ctx->mark_non_differentiable({out.median_depth, out.max_weight});
    return {out.rgb, out.alpha, out.depth, out.median_depth, out.max_weight};
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const GaussianInputs in =
        inputs_of(saved[0], saved[1], saved[2], saved[3], saved[4], render::load_call<CompositingConstants>(ctx));
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
      if (views.empty()) return variable_list(6);
      g = cuda::backward(in, views, g_rgb, g_alpha, g_depth);
#endif
    } else {
      g = cpu::backward(in, g_rgb, g_alpha, g_depth);
    }
    return {g.means, g.scales, g.rotations, g.colors, g.opacities, at::Tensor()};  // the call gets none
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
  const auto opts = render::compute_options(means);
  const std::vector<at::Tensor> t = render::to_compute({means, scales, rotations, colors, opacities}, opts);
  Call call = render::make_call(host_cams, height, width, settings, opts, settings.constants());
  // The value checks' statistics: on the GPU copied to the host without a
  // sync, checked at the CUDA back end's first wait for the device.
  call.value_stats = means.size(0) > 0 ? render::to_host_async(render::input_stats(t, t[4], t[1], t[2]))
                                       : at::empty({0}, at::kDouble);
  if (!means.is_cuda()) check_input_values(inputs_of(t[0], t[1], t[2], t[3], t[4], call));
  auto outs = RasterizeGaussiansFunction::apply(t[0], t[1], t[2], t[3], t[4], call);
  render::RenderOutput r;
  r.rgb = outs[0];
  r.alpha = outs[1];
  r.depth = outs[2];
  r.median_depth = outs[3];
  r.max_weight = outs[4];
  return r;  // normal and distortion stay undefined
}

}  // namespace flat::gaussians
