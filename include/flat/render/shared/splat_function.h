// The autograd Function of the 3DGS and 2DGS rasterizers (gaussians/,
// surfels/): the same five inputs (means, scales, rotations, colors,
// opacities), the same dispatch to the CPU reference or the CUDA kernels and
// the same state kept for the backward; only the back ends and which images
// they give differ. Public, under flat/render/shared/, because gaussians and
// surfels include it; not part of the rasterizer's API.
//
// Each rasterizer instantiates SplatFunction with its SplatKind and its back
// ends (flat::gaussians: the kind, cpu::forward, cpu::backward, cuda::forward,
// cuda::backward):
//   cpu_forward:   RenderOutput (const SplatInputs&)
//   cpu_backward:  SplatGrads (const SplatInputs&, const SplatOutputGrads&)
//   cuda_forward:  RenderOutput (const SplatInputs&, bool for_backward, std::vector<at::Tensor>& views)
//                  (for_backward: keep the per-view state in `views`, else it stays empty)
//   cuda_backward: SplatGrads (const SplatInputs&, const std::vector<at::Tensor>& views, const SplatOutputGrads&)
// The CUDA ones left out (a build without CUDA kernels): CUDA inputs fail.
#pragma once
#include <string>
#include <type_traits>
#include <vector>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>

#include "flat/camera/cameras.h"
#include "flat/core/error.h"
#include "flat/render/rasterize.h"
#include "flat/render/shared/raster_dispatch.h"
#include "flat/render/shared/splat_buffers.h"

namespace flat::render {

using SplatCall = RasterCall<CompositingConstants>;

// Which rasterizer, and what of it the shared code reads.
struct SplatKind {
  const char* name;         // in errors: "rasterize_gaussians"
  int64_t scale_dims;       // scales are (N, scale_dims)
  bool normal, distortion;  // images besides rgb, alpha, depth and median_depth
  // The CUDA back end checks the value statistics at its first wait for the
  // device (check_splat_values), so the GPU does not idle through the
  // call's setup; else they are read and checked before the call.
  bool cuda_checks_values;
};

// The back ends' inputs: the five (in compute_options' dtype, contiguous)
// and the call's views, size, constants and value statistics.
SplatInputs splat_inputs(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                         const at::Tensor& colors, const at::Tensor& opacities, const SplatCall& call);

// The Function's outputs in their order: rgb, alpha, depth, [normal],
// median_depth, max_weight, [distortion] (bracketed: where the rasterizer has
// them); splat_output() reads them back.
torch::autograd::variable_list splat_outputs(const RenderOutput& out, const SplatKind& kind);
RenderOutput splat_output(const torch::autograd::variable_list& outs, const SplatKind& kind);

// The upstream gradients of those outputs (grads in the same order) for
// inputs `in`: zeros where autograd gave none.
SplatOutputGrads splat_output_grads(const torch::autograd::variable_list& grads, const SplatInputs& in,
                                    const SplatKind& kind);

// The five inputs checked (shapes, cameras, image size, devices) and in the
// back ends' dtype and layout, with their call; the value checks done or,
// for CUDA inputs of a kind that checks them there, their statistics on the way.
struct PreparedSplats {
  std::vector<at::Tensor> inputs;  // means, scales, rotations, colors, opacities
  SplatCall call;
};
PreparedSplats prepare_splats(const SplatKind& kind, const at::Tensor& means, const at::Tensor& scales,
                              const at::Tensor& rotations, const at::Tensor& colors, const at::Tensor& opacities,
                              const camera::Cameras& cams, int64_t height, int64_t width,
                              const CompositingSettings& settings);

template <const SplatKind& kKind, auto cpu_forward, auto cpu_backward, auto cuda_forward = nullptr,
          auto cuda_backward = nullptr>
struct SplatFunction
    : public torch::autograd::Function<SplatFunction<kKind, cpu_forward, cpu_backward, cuda_forward, cuda_backward>> {
  using AutogradContext = torch::autograd::AutogradContext;
  using variable_list = torch::autograd::variable_list;
  static constexpr bool kWithCuda = !std::is_null_pointer_v<decltype(cuda_forward)>;

  // The rasterizer's whole call: prepare_splats, then the Function.
  static RenderOutput rasterize(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                                const at::Tensor& colors, const at::Tensor& opacities, const camera::Cameras& cams,
                                int64_t height, int64_t width, const CompositingSettings& settings) {
    const PreparedSplats p =
        prepare_splats(kKind, means, scales, rotations, colors, opacities, cams, height, width, settings);
    const std::vector<at::Tensor>& t = p.inputs;
    return splat_output(SplatFunction::apply(t[0], t[1], t[2], t[3], t[4], p.call), kKind);
  }

  static variable_list forward(AutogradContext* ctx, const at::Tensor& means, const at::Tensor& scales,
                               const at::Tensor& rotations, const at::Tensor& colors, const at::Tensor& opacities,
                               const SplatCall& call) {
    const SplatInputs in = splat_inputs(means, scales, rotations, colors, opacities, call);
    RenderOutput out;
    if (!means.is_cuda()) {
      out = cpu_forward(in);
    } else if constexpr (kWithCuda) {
      std::vector<at::Tensor> views;
      const bool for_backward = means.requires_grad() || scales.requires_grad() || rotations.requires_grad() ||
                                colors.requires_grad() || opacities.requires_grad();
      out = cuda_forward(in, for_backward, views);
      ctx->saved_data["views"] = views;
    } else {
      fail(std::string(kKind.name) + ": tensors are on CUDA but this build has no CUDA kernels (FLAT_WITH_CUDA=OFF)");
    }
    ctx->save_for_backward({means, scales, rotations, colors, opacities});
    save_call(ctx, call);
    ctx->mark_non_differentiable({out.median_depth, out.max_weight});
    return splat_outputs(out, kKind);
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const SplatInputs in =
        splat_inputs(saved[0], saved[1], saved[2], saved[3], saved[4], load_call<CompositingConstants>(ctx));
    const SplatOutputGrads up = splat_output_grads(grads, in, kKind);
    SplatGrads g;
    if (!in.means.is_cuda()) {
      g = cpu_backward(in, up);
    } else if constexpr (kWithCuda) {  // (else the forward failed)
      const auto views = ctx->saved_data["views"].toTensorVector();
      // No state was kept when no scene input required grad: nothing to compute.
      if (views.empty()) return variable_list(6);
      g = cuda_backward(in, views, up);
    }
    return {g.means, g.scales, g.rotations, g.colors, g.opacities, at::Tensor()};  // the call gets none
  }
};

}  // namespace flat::render
