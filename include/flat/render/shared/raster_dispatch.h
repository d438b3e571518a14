// Host-side glue shared by the three rasterizers' autograd dispatch
// (render/rasterize.cpp, gaussians/rasterize_gaussians.cpp,
// surfels/rasterize_surfels.cpp): the compositing constants from the settings
// and through the autograd context, the input checks every primitive has, the
// back ends' dtype, the cameras on the host and the value checks' statistics.
// Public, under flat/render/shared/, because the gaussians and surfels
// modules include it (a module includes only another's public headers);
// not part of the rasterizer's API. The primitive-specific parts stay in
// each module; the definitions are in src/render/raster_dispatch.cpp.
#pragma once
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>

#include "flat/camera/cameras.h"
#include "flat/core/error.h"
#include "flat/render/rasterize.h"

namespace flat::render {

// ---------------------------------------------------------------- constants
// The constants struct K (CompositingConstants, or the triangles'
// RasterConstants) and the image size, kept in the autograd context
// for the backward as ONE small byte tensor (K is trivially copyable): no
// string key per field, and a field added to K travels without a line here.
template <class K>
struct SavedConstants {
  K k;
  int64_t height = 0, width = 0;
};

template <class K>
void save_constants(torch::autograd::AutogradContext* ctx, const K& k, int64_t height, int64_t width) {
  static_assert(std::is_trivially_copyable_v<K>, "the constants are saved as bytes");
  const SavedConstants<K> saved{k, height, width};
  at::Tensor bytes = at::empty({int64_t(sizeof(saved))}, at::kByte);
  std::memcpy(bytes.data_ptr(), &saved, sizeof(saved));
  ctx->saved_data["constants"] = bytes;
}

template <class K>
SavedConstants<K> load_constants(torch::autograd::AutogradContext* ctx) {
  const at::Tensor bytes = ctx->saved_data["constants"].toTensor();
  SavedConstants<K> saved;
  FLAT_CHECK(bytes.numel() == int64_t(sizeof(saved)), "rasterize: saved constants of the wrong size");
  std::memcpy(&saved, bytes.data_ptr(), sizeof(saved));
  return saved;
}

// The upstream gradient of a (V,C,H,W) output in `opts`; zeros where autograd
// gave none (the output was unused), so the back ends always read one.
at::Tensor grad_or_zero(const at::Tensor& grad, const at::TensorOptions& opts, int64_t V, int64_t C, int64_t H,
                        int64_t W);

// ---------------------------------------------------------------- outputs
// The images of `views` views of height x width pixels in `opts`,
// uninitialised (the back ends write every pixel): rgb, alpha, depth and
// median_depth, and normal and distortion where asked; max_weight is left
// to the back end (its accumulation type differs).
RenderOutput empty_images(int64_t views, int64_t height, int64_t width, const at::TensorOptions& opts, bool normal,
                          bool distortion);

// ---------------------------------------------------------------- inputs
// The checks every rasterizer's inputs share, after its own shape checks;
// `fn` names the rasterizer in the messages, `names` the inputs in the device
// message ("vertices, colors, opacities and sigmas"): valid cameras, a
// positive image size of at most 2^30 pixels, floating-point inputs on one
// CPU or CUDA device.
void check_common_inputs(const std::string& fn, const std::vector<at::Tensor>& inputs, const std::string& names,
                         const camera::Cameras& cams, int64_t height, int64_t width);

// The back ends' options for inputs on lead's device: float32, except that
// all-double CPU inputs run the reference in double (finite differences).
at::TensorOptions compute_options(const at::Tensor& lead);

// The inputs in `opts` (compute_options()), contiguous, in their order.
std::vector<at::Tensor> to_compute(const std::vector<at::Tensor>& inputs, const at::TensorOptions& opts);

// The cameras and background as both back ends read them: on the host (a few
// hundred bytes; each check or small op on the GPU would cost a sync or a
// launch) in the dtype of `opts`: w2c (V,4,4), K (V,4) pixel intrinsics fx,
// fy, cx, cy, background (3). host_cams: the cameras already on the host.
struct HostViews {
  at::Tensor w2c, K, background;
};
HostViews host_views(const camera::Cameras& host_cams, int64_t height, int64_t width, const CompositingSettings& settings,
                     const at::TensorOptions& opts);

// ---------------------------------------------------------------- autograd
// What a rasterizer's autograd Function takes besides its differentiable
// inputs, as one argument: the views, the image size, the constants K
// (CompositingConstants, or the triangles' RasterConstants) and the value
// checks' statistics (input_stats(), on the host; empty: nothing to check).
template <class K>
struct RasterCall {
  HostViews views;
  int64_t height = 0, width = 0;
  K k;
  at::Tensor value_stats;
};

// The call of checked settings k: the views of host_cams in the dtype of
// `opts`, no statistics yet.
template <class K>
RasterCall<K> make_call(const camera::Cameras& host_cams, int64_t height, int64_t width,
                        const CompositingSettings& settings, const at::TensorOptions& opts, const K& k) {
  return {host_views(host_cams, height, width, settings, opts), height, width, k, at::Tensor()};
}

// Keeps the call in the autograd context for the backward (not the
// statistics, which the forward has checked).
template <class K>
void save_call(torch::autograd::AutogradContext* ctx, const RasterCall<K>& call) {
  ctx->saved_data["w2c"] = call.views.w2c;
  ctx->saved_data["K"] = call.views.K;
  ctx->saved_data["background"] = call.views.background;
  save_constants(ctx, call.k, call.height, call.width);
}

template <class K>
RasterCall<K> load_call(torch::autograd::AutogradContext* ctx) {
  const SavedConstants<K> c = load_constants<K>(ctx);
  RasterCall<K> call;
  call.views = {ctx->saved_data["w2c"].toTensor(), ctx->saved_data["K"].toTensor(),
                ctx->saved_data["background"].toTensor()};
  call.height = c.height;
  call.width = c.width;
  call.k = c.k;
  return call;
}

// ---------------------------------------------------------------- value checks
// The value checks' statistics on the inputs' device, one reduction each:
// [sum of every input value (finite or not), min and max opacity, min of the
// input that must be positive (sigmas, scales), and when `quaternions` is
// defined the min of their squared norms].
at::Tensor input_stats(const std::vector<at::Tensor>& inputs, const at::Tensor& opacities, const at::Tensor& positive,
                       const at::Tensor& quaternions = at::Tensor());

// A CUDA tensor copied to pinned host memory without a sync (read it only
// once the stream that computed it has been waited for, so the GPU does not
// idle through the call's setup); a host tensor as it is.
at::Tensor to_host_async(const at::Tensor& t);

// Fails unless the statistics `s` (input_stats, read on the host) say the
// inputs are finite (else check_finite names the first bad one), opacities
// lie in [0, 1], the positive input is > 0 and quaternions (when there were
// any) are non-zero. inputs / names as given to input_stats; `positive` names
// the positive input.
void check_input_stats(const double* s, const std::string& fn, const std::vector<at::Tensor>& inputs,
                       const std::vector<std::string>& names, const std::string& positive, bool quaternions);

}  // namespace flat::render
