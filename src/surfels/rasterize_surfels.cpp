// rasterize_surfels(): input checks, dtype/device dispatch and the autograd
// Function with the analytic backward (CPU reference or CUDA kernels).
#include "flat/surfels/rasterize_surfels.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/render/shared/raster_dispatch.h"
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

using Call = render::RasterCall<CompositingConstants>;

SurfelInputs inputs_of(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                       const at::Tensor& colors, const at::Tensor& opacities, const Call& c) {
  return {means, scales, rotations, colors, opacities, c.views.w2c, c.views.K, c.views.background,
          c.height, c.width, c.k};
}

struct RasterizeSurfelsFunction : public torch::autograd::Function<RasterizeSurfelsFunction> {
  static variable_list forward(AutogradContext* ctx, const at::Tensor& means, const at::Tensor& scales,
                               const at::Tensor& rotations, const at::Tensor& colors, const at::Tensor& opacities,
                               const Call& call) {
    const SurfelInputs in = inputs_of(means, scales, rotations, colors, opacities, call);
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
    ctx->save_for_backward({means, scales, rotations, colors, opacities});
    render::save_call(ctx, call);
    ctx->mark_non_differentiable({out.median_depth, out.max_weight});
    return {out.rgb, out.alpha, out.depth, out.normal, out.median_depth, out.max_weight, out.distortion};
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const SurfelInputs in =
        inputs_of(saved[0], saved[1], saved[2], saved[3], saved[4], render::load_call<CompositingConstants>(ctx));
    const int64_t V = in.w2c.size(0), H = in.height, W = in.width;
    const auto opts = in.means.options();
    auto grad_or_zero = [&](const at::Tensor& g, int64_t C) { return render::grad_or_zero(g, opts, V, C, H, W); };
    const SurfelOutputGrads up{grad_or_zero(grads[0], 3), grad_or_zero(grads[1], 1), grad_or_zero(grads[2], 1),
                               grad_or_zero(grads[3], 3), grad_or_zero(grads[6], 1)};
    SurfelGrads g;
    if (in.means.is_cuda()) {
#if FLAT_WITH_CUDA
      const auto views = ctx->saved_data["views"].toTensorVector();
      // No state was kept when no scene input required grad: nothing to compute.
      if (views.empty()) return variable_list(6);
      g = cuda::backward(in, views, up);
#endif
    } else {
      g = cpu::backward(in, up);
    }
    return {g.means, g.scales, g.rotations, g.colors, g.opacities, at::Tensor()};  // the call gets none
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
  render::check_common_inputs("rasterize_surfels", {means, scales, rotations, colors, opacities},
                              "means, scales, rotations, colors and opacities", cams, height, width);
}

// Finite values, opacities in [0, 1], scales > 0, non-zero quaternions of
// the inputs (means, scales, rotations, colors, opacities): one reduction
// each, read with one host copy (a sync on the GPU).
void check_values(const std::vector<at::Tensor>& inputs) {
  if (inputs[0].size(0) == 0) return;
  const at::Tensor stats = render::input_stats(inputs, inputs[4], inputs[1], inputs[2]).cpu();
  render::check_input_stats(stats.data_ptr<double>(), "rasterize_surfels", inputs,
                            {"means", "scales", "rotations", "colors", "opacities"}, "scales", true);
}

}  // namespace

render::RenderOutput rasterize_surfels(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                                       const at::Tensor& colors, const at::Tensor& opacities,
                                       const camera::Cameras& cams, int64_t height, int64_t width,
                                       const render::CompositingSettings& settings) {
  settings.check();
  const camera::Cameras host_cams = cams.to(at::kCPU);  // both back ends read them there
  check_inputs(means, scales, rotations, colors, opacities, host_cams, height, width);
  const auto opts = render::compute_options(means);
  const std::vector<at::Tensor> t = render::to_compute({means, scales, rotations, colors, opacities}, opts);
  check_values(t);
  const Call call = render::make_call(host_cams, height, width, settings, opts, settings.constants());
  auto outs = RasterizeSurfelsFunction::apply(t[0], t[1], t[2], t[3], t[4], call);
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
