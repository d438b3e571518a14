// rasterize(): input checks, dtype/device dispatch and the autograd Function
// with the analytic backward (CPU reference or CUDA kernels).
#include "flat/render/rasterize.h"
#include "flat/render/raster_load.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "render/cpu/raster_cpu.h"
#include "flat/render/shared/raster_dispatch.h"
#if FLAT_WITH_CUDA
#include "render/cuda/raster_cuda.h"
#endif

namespace flat::render {

void CompositingSettings::check_relations() const {
  FLAT_CHECK(background.size() == 3, "raster settings: 'background' must have 3 values (r,g,b), got " +
                                         std::to_string(background.size()));
  FLAT_CHECK(alpha_min < alpha_max, "raster settings: 'alpha_min' (" + std::to_string(alpha_min) +
                                        ") must be below 'alpha_max' (" + std::to_string(alpha_max) + ")");
}

void CompositingSettings::check() const {
  // The ranges live in visit(); here only what relates fields to each other.
  config::validate_fields(*this, "raster settings");
  check_relations();
}

void RasterSettings::check() const {
  config::validate_fields(*this, "raster settings");
  check_relations();
}

CompositingConstants CompositingSettings::constants() const {
  CompositingConstants k;
  k.near_plane = (float)near_plane;
  k.alpha_max = (float)alpha_max;
  k.alpha_min = (float)alpha_min;
  k.t_min = (float)transmittance_min;
  return k;
}

namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

RasterConstants to_constants(const RasterSettings& s) {
  RasterConstants k;
  static_cast<CompositingConstants&>(k) = s.constants();
  k.eps = (float)s.eps;
  k.min_inradius = (float)s.min_inradius;
  k.min_cos = (float)s.min_cos;
  k.window = s.window == "ts" ? kWindowTS : kWindowFlat;
  return k;
}

using Call = RasterCall<RasterConstants>;

// vertices as (N,9) rows.
RasterInputs inputs_of(const at::Tensor& vertices, const at::Tensor& colors, const at::Tensor& opacities,
                       const at::Tensor& sigmas, const Call& c, int64_t views_per_bin) {
  RasterInputs in{vertices.reshape({vertices.size(0), 9}), colors, opacities, sigmas, c.views.w2c, c.views.K,
                  c.views.background, c.height, c.width, c.k};
  in.views_per_bin = views_per_bin;
  in.value_stats = c.value_stats;
  return in;
}

struct RasterizeFunction : public torch::autograd::Function<RasterizeFunction> {
  static variable_list forward(AutogradContext* ctx, const at::Tensor& vertices, const at::Tensor& colors,
                               const at::Tensor& opacities, const at::Tensor& sigmas, const Call& call,
                               int64_t views_per_bin) {
    const RasterInputs in = inputs_of(vertices, colors, opacities, sigmas, call, views_per_bin);
    RasterOutputs out;
    if (vertices.is_cuda()) {
#if FLAT_WITH_CUDA
      std::vector<at::Tensor> views;
      const bool for_backward = vertices.requires_grad() || colors.requires_grad() || opacities.requires_grad() ||
                                sigmas.requires_grad();
      out = cuda::forward(in, for_backward, views);
      ctx->saved_data["views"] = views;
#else
      fail("rasterize: tensors are on CUDA but this build has no CUDA kernels (FLAT_WITH_CUDA=OFF)");
#endif
    } else {
      out = cpu::forward(in);
    }
    ctx->save_for_backward({vertices, colors, opacities, sigmas});
    save_call(ctx, call);
    ctx->saved_data["views_per_bin"] = views_per_bin;
    ctx->mark_non_differentiable({out.median_depth, out.max_weight});
    return {out.rgb, out.alpha, out.depth, out.normal, out.median_depth, out.max_weight};
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const RasterInputs in = inputs_of(saved[0], saved[1], saved[2], saved[3], load_call<RasterConstants>(ctx),
                                      ctx->saved_data["views_per_bin"].toInt());
    const int64_t V = in.w2c.size(0), H = in.height, W = in.width;
    const auto opts = in.vertices.options();
    const at::Tensor g_rgb = grad_or_zero(grads[0], opts, V, 3, H, W), g_alpha = grad_or_zero(grads[1], opts, V, 1, H, W);
    const at::Tensor g_depth = grad_or_zero(grads[2], opts, V, 1, H, W);
    const at::Tensor g_normal = grad_or_zero(grads[3], opts, V, 3, H, W);
    RasterGrads g;
    if (in.vertices.is_cuda()) {
#if FLAT_WITH_CUDA
      const auto views = ctx->saved_data["views"].toTensorVector();
      // No state was kept when no scene input required grad (only the
      // cameras did, which get no gradient): nothing to compute.
      if (views.empty()) return variable_list(6);
      g = cuda::backward(in, views, g_rgb, g_alpha, g_depth, g_normal);
#endif
    } else {
      g = cpu::backward(in, g_rgb, g_alpha, g_depth, g_normal);
    }
    // The call and views_per_bin get none.
    return {g.vertices.view_as(saved[0]), g.colors, g.opacities, g.sigmas, at::Tensor(), at::Tensor()};
  }
};

void check_inputs(const at::Tensor& vertices, const at::Tensor& colors, const at::Tensor& opacities,
                  const at::Tensor& sigmas, const camera::Cameras& cams, int64_t height, int64_t width) {
  check_shape(vertices, {-1, 3, 3}, "rasterize: vertices", "(N,3,3)");
  const int64_t N = vertices.size(0);
  check_shape(colors, {N, 3}, "rasterize: colors", "(N,3) with N = " + std::to_string(N));
  check_shape(opacities, {N}, "rasterize: opacities", "(N) with N = " + std::to_string(N));
  check_shape(sigmas, {N}, "rasterize: sigmas", "(N) with N = " + std::to_string(N));
  check_common_inputs("rasterize", {vertices, colors, opacities, sigmas}, "vertices, colors, opacities and sigmas", cams,
                      height, width);
}

}  // namespace

void check_input_values(const RasterInputs& in) {
  if (in.value_stats.numel() == 0) return;  // no triangles: nothing to check
  check_input_stats(in.value_stats.data_ptr<double>(), "rasterize", {in.vertices, in.colors, in.opacities, in.sigmas},
                    {"vertices", "colors", "opacities", "sigmas"}, "sigmas", false);
}

namespace {

// Checked inputs in the back ends' dtype and layout, and the call.
struct Prepared {
  at::Tensor vertices, colors, opacities, sigmas;
  Call call;
  int64_t views_per_bin = 2;
  RasterInputs inputs() const { return inputs_of(vertices, colors, opacities, sigmas, call, views_per_bin); }
};

Prepared prepare(const at::Tensor& vertices, const at::Tensor& colors, const at::Tensor& opacities,
                 const at::Tensor& sigmas, const camera::Cameras& cams, int64_t height, int64_t width,
                 const RasterSettings& settings) {
  settings.check();
  const camera::Cameras host_cams = cams.to(at::kCPU);  // both back ends read them there
  check_inputs(vertices, colors, opacities, sigmas, host_cams, height, width);
  const auto opts = compute_options(vertices);
  auto prep = [&](const at::Tensor& t) { return t.to(opts).contiguous(); };
  Prepared p{prep(vertices), prep(colors), prep(opacities), prep(sigmas),
             make_call(host_cams, height, width, settings, opts, to_constants(settings)), settings.views_per_bin};
  // The value checks' statistics: on the GPU copied to the host without a
  // sync, checked at the CUDA back end's first wait for the device
  // (cuda::forward), so the GPU does not idle through the call's setup.
  p.call.value_stats = p.vertices.size(0) > 0
                           ? to_host_async(input_stats({p.vertices, p.colors, p.opacities, p.sigmas}, p.opacities,
                                                       p.sigmas))
                           : at::empty({0}, at::kDouble);
  if (!vertices.is_cuda()) check_input_values(p.inputs());  // else at the CUDA back end's first sync
  return p;
}

}  // namespace

RenderOutput rasterize(const at::Tensor& vertices, const at::Tensor& colors, const at::Tensor& opacities,
                       const at::Tensor& sigmas, const camera::Cameras& cams, int64_t height, int64_t width,
                       const RasterSettings& settings) {
  const Prepared p = prepare(vertices, colors, opacities, sigmas, cams, height, width, settings);
  auto outs = RasterizeFunction::apply(p.vertices, p.colors, p.opacities, p.sigmas, p.call, p.views_per_bin);
  return RenderOutput{outs[0], outs[1], outs[2], outs[3], outs[4], outs[5]};
}

std::vector<ViewLoad> measure_raster_load(const at::Tensor& vertices, const at::Tensor& colors,
                                          const at::Tensor& opacities, const at::Tensor& sigmas,
                                          const camera::Cameras& cams, int64_t height, int64_t width,
                                          const RasterSettings& settings) {
  FLAT_CHECK(vertices.is_cuda(), "measure_raster_load: the load counts describe the CUDA tiling; give CUDA tensors");
  std::vector<ViewLoad> load;
#if FLAT_WITH_CUDA
  at::NoGradGuard no_grad;
  const RasterInputs in = prepare(vertices, colors, opacities, sigmas, cams, height, width, settings).inputs();
  std::vector<at::Tensor> views;
  cuda::forward(in, false, views, &load);
#else
  fail("measure_raster_load: this build has no CUDA kernels (FLAT_WITH_CUDA=OFF)");
#endif
  return load;
}

}  // namespace flat::render
