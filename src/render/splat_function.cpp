// The non-template parts of the splat rasterizers' autograd Function
// (flat/render/shared/splat_function.h).
#include "flat/render/shared/splat_function.h"

#include <string>

#include "flat/core/shape.h"

namespace flat::render {

SplatInputs splat_inputs(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                         const at::Tensor& colors, const at::Tensor& opacities, const SplatCall& call) {
  return {means,    scales,          rotations,          colors,      opacities, call.views.w2c,
          call.views.K, call.views.background, call.height, call.width, call.k,    call.value_stats};
}

torch::autograd::variable_list splat_outputs(const RenderOutput& out, const SplatKind& kind) {
  torch::autograd::variable_list outs = {out.rgb, out.alpha, out.depth};
  if (kind.normal) outs.push_back(out.normal);
  outs.push_back(out.median_depth);
  outs.push_back(out.max_weight);
  if (kind.distortion) outs.push_back(out.distortion);
  return outs;
}

RenderOutput splat_output(const torch::autograd::variable_list& outs, const SplatKind& kind) {
  RenderOutput r;
  size_t i = 0;
  r.rgb = outs[i++];
  r.alpha = outs[i++];
  r.depth = outs[i++];
  if (kind.normal) r.normal = outs[i++];
  r.median_depth = outs[i++];
  r.max_weight = outs[i++];
  if (kind.distortion) r.distortion = outs[i++];
  return r;
}

SplatOutputGrads splat_output_grads(const torch::autograd::variable_list& grads, const SplatInputs& in,
                                    const SplatKind& kind) {
  const int64_t V = in.w2c.size(0), H = in.height, W = in.width;
  const auto opts = in.means.options();
  auto grad = [&](size_t i, int64_t channels) { return grad_or_zero(grads[i], opts, V, channels, H, W); };
  SplatOutputGrads up;
  up.rgb = grad(0, 3);
  up.alpha = grad(1, 1);
  up.depth = grad(2, 1);
  if (kind.normal) up.normal = grad(3, 3);
  // median_depth and max_weight (no gradient) come next; distortion last.
  if (kind.distortion) up.distortion = grad(grads.size() - 1, 1);
  return up;
}

void check_splat_values(const SplatInputs& in, const char* fn) {
  if (in.value_stats.numel() == 0) return;
  check_input_stats(in.value_stats.data_ptr<double>(), fn, {in.means, in.scales, in.rotations, in.colors, in.opacities},
                    {"means", "scales", "rotations", "colors", "opacities"}, "scales", true);
}

namespace {

// "rasterize_surfels: scales: expected shape (N,2) with N = 5, got (5,3)".
void check_shapes(const SplatKind& kind, const at::Tensor& means, const at::Tensor& scales,
                  const at::Tensor& rotations, const at::Tensor& colors, const at::Tensor& opacities) {
  const std::string fn = std::string(kind.name) + ": ";
  check_shape(means, {-1, 3}, fn + "means", "(N,3)");
  const int64_t N = means.size(0);
  const std::string n = " with N = " + std::to_string(N);
  check_shape(scales, {N, kind.scale_dims}, fn + "scales", "(N," + std::to_string(kind.scale_dims) + ")" + n);
  check_shape(rotations, {N, 4}, fn + "rotations", "(N,4) quaternions (w,x,y,z)" + n);
  check_shape(colors, {N, 3}, fn + "colors", "(N,3)" + n);
  check_shape(opacities, {N}, fn + "opacities", "(N)" + n);
}

}  // namespace

PreparedSplats prepare_splats(const SplatKind& kind, const at::Tensor& means, const at::Tensor& scales,
                              const at::Tensor& rotations, const at::Tensor& colors, const at::Tensor& opacities,
                              const camera::Cameras& cams, int64_t height, int64_t width,
                              const CompositingSettings& settings) {
  settings.check();
  const camera::Cameras host_cams = cams.to(at::kCPU);  // both back ends read them there
  check_shapes(kind, means, scales, rotations, colors, opacities);
  check_common_inputs(kind.name, {means, scales, rotations, colors, opacities},
                      "means, scales, rotations, colors and opacities", host_cams, height, width);
  const auto opts = compute_options(means);
  PreparedSplats p{to_compute({means, scales, rotations, colors, opacities}, opts),
                   make_call(host_cams, height, width, settings, opts, settings.constants())};
  const std::vector<at::Tensor>& t = p.inputs;
  if (t[0].size(0) == 0) {
    p.call.value_stats = at::empty({0}, at::kDouble);  // no splats: nothing to check
    return p;
  }
  // The statistics of all values in one reduction each; on the GPU either
  // copied to the host without a sync (checked by the back end) or read now.
  const at::Tensor stats = input_stats(t, t[4], t[1], t[2]);
  const bool on_device = means.is_cuda() && kind.cuda_checks_values;
  p.call.value_stats = on_device ? to_host_async(stats) : stats.cpu();
  if (!on_device) check_splat_values(splat_inputs(t[0], t[1], t[2], t[3], t[4], p.call), kind.name);
  return p;
}

}  // namespace flat::render
