// Host-side glue shared by the three rasterizers' dispatch (raster_dispatch.h).
#include "flat/render/shared/raster_dispatch.h"

#include <cmath>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::render {

at::Tensor grad_or_zero(const at::Tensor& grad, const at::TensorOptions& opts, int64_t V, int64_t C, int64_t H,
                        int64_t W) {
  return grad.defined() ? grad.to(opts).contiguous() : at::zeros({V, C, H, W}, opts);
}

RenderOutput empty_images(int64_t views, int64_t height, int64_t width, const at::TensorOptions& opts, bool normal,
                          bool distortion) {
  auto image = [&](int64_t channels) { return at::empty({views, channels, height, width}, opts); };
  RenderOutput out;
  out.rgb = image(3);
  out.alpha = image(1);
  out.depth = image(1);
  if (normal) out.normal = image(3);
  out.median_depth = image(1);
  if (distortion) out.distortion = image(1);
  return out;
}

void check_common_inputs(const std::string& fn, const std::vector<at::Tensor>& inputs, const std::string& names,
                         const camera::Cameras& cams, int64_t height, int64_t width) {
  cams.check(fn + ": cameras");
  FLAT_CHECK(height > 0 && width > 0,
             fn + ": image size must be positive, got " + std::to_string(height) + "x" + std::to_string(width));
  FLAT_CHECK(height * width <= (int64_t(1) << 30),
             fn + ": image too large (" + std::to_string(height) + "x" + std::to_string(width) + ")");
  for (const at::Tensor& t : inputs)
    FLAT_CHECK(t.is_floating_point(),
               fn + ": inputs must be floating point, got " + std::string(c10::toString(t.scalar_type())));
  const auto dev = inputs.front().device();
  for (const at::Tensor& t : inputs) FLAT_CHECK(t.device() == dev, fn + ": " + names + " must be on one device");
  FLAT_CHECK(dev.is_cpu() || dev.is_cuda(), fn + ": unsupported device " + dev.str());
}

at::TensorOptions compute_options(const at::Tensor& lead) {
  const bool use_double = lead.device().is_cpu() && lead.scalar_type() == at::kDouble;
  return at::TensorOptions().device(lead.device()).dtype(use_double ? at::kDouble : at::kFloat);
}

std::vector<at::Tensor> to_compute(const std::vector<at::Tensor>& inputs, const at::TensorOptions& opts) {
  std::vector<at::Tensor> out;
  for (const at::Tensor& t : inputs) out.push_back(t.to(opts).contiguous());
  return out;
}

HostViews host_views(const camera::Cameras& host_cams, int64_t height, int64_t width,
                     const CompositingSettings& settings,
                     const at::TensorOptions& opts) {
  const auto host = opts.device(at::kCPU);
  HostViews h;
  h.w2c = camera::world_to_camera(host_cams.c2w.to(host).to(at::kDouble)).to(host).contiguous();
  h.K = camera::pixel_intrinsics(host_cams.intrinsics.to(host), height, width).contiguous();
  h.background = at::tensor(settings.background, at::TensorOptions().dtype(at::kDouble)).to(host);
  return h;
}

at::Tensor input_stats(const std::vector<at::Tensor>& inputs, const at::Tensor& opacities, const at::Tensor& positive,
                       const at::Tensor& quaternions) {
  at::Tensor sum = inputs.front().sum();
  for (size_t i = 1; i < inputs.size(); ++i) sum = sum + inputs[i].sum();
  std::vector<at::Tensor> stats = {sum.to(at::kDouble), opacities.min().to(at::kDouble),
                                   opacities.max().to(at::kDouble), positive.min().to(at::kDouble)};
  if (quaternions.defined()) stats.push_back(quaternions.square().sum(1).min().to(at::kDouble));
  return at::stack(stats);
}

at::Tensor to_host_async(const at::Tensor& t) {
  if (!t.is_cuda()) return t;
  at::Tensor host = at::empty(t.sizes(), t.options().device(at::kCPU).pinned_memory(true));
  host.copy_(t, /*non_blocking=*/true);
  return host;
}

void check_input_stats(const double* s, const std::string& fn, const std::vector<at::Tensor>& inputs,
                       const std::vector<std::string>& names, const std::string& positive, bool quaternions) {
  if (!std::isfinite(s[0]))
    for (size_t i = 0; i < inputs.size(); ++i) check_finite(inputs[i], fn + ": " + names[i]);
  FLAT_CHECK(s[1] >= 0.0 && s[2] <= 1.0, fn + ": opacities must lie in [0, 1], got range [" + std::to_string(s[1]) +
                                             ", " + std::to_string(s[2]) + "]");
  FLAT_CHECK(s[3] > 0.0, fn + ": " + positive + " must be > 0, got min " + std::to_string(s[3]));
  if (quaternions) FLAT_CHECK(s[4] > 0.0, fn + ": rotations must be non-zero quaternions (w,x,y,z), got one of norm 0");
}

}  // namespace flat::render
