#include "loss/lpips_tap_distance.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"

#if FLAT_WITH_CUDA
#include <ATen/cuda/CUDAContext.h>
#include <torch/csrc/autograd/custom_function.h>

#include "loss/cuda/lpips_tap_kernel.h"
#endif

namespace flat::loss {
namespace {

at::Tensor aten_tap_distance(const at::Tensor& fa, const at::Tensor& fb, const at::Tensor& w) {
  const auto dtype = fa.scalar_type() == at::kDouble ? at::kDouble : at::kFloat;
  auto unit = [&](const at::Tensor& f) {
    auto x = f.to(dtype);
    return x / (x.square().sum(1, true).sqrt() + 1e-10);
  };
  auto per_channel = (unit(fa) - unit(fb)).square().mean({2, 3});  // (V,C)
  return at::matmul(per_channel, w.reshape({-1}).to(dtype));
}

#if FLAT_WITH_CUDA
// The fused kernels as one autograd node. Forward: a distance per pixel, then
// the mean over each view's pixels.
struct LpipsTapFunction : public torch::autograd::Function<LpipsTapFunction> {
  static at::Tensor forward(torch::autograd::AutogradContext* ctx, const at::Tensor& fa, const at::Tensor& fb,
                            const at::Tensor& w) {
    const int64_t V = fa.size(0), C = fa.size(1), P = fa.size(2) * fa.size(3);
    const at::Tensor wf = w.reshape({-1}).to(at::kFloat).contiguous();
    ctx->save_for_backward({fa, fb, wf});
    at::Tensor pixel = at::empty({V, P}, fa.options().dtype(at::kFloat));
    cuda::launch_lpips_tap_forward(fa.data_ptr(), fb.data_ptr(), wf.data_ptr<float>(), pixel.data_ptr<float>(), V * P,
                                   C, at::cuda::getCurrentCUDAStream());
    return pixel.mean(1);
  }

  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    if (!grads[0].defined()) return {at::Tensor(), at::Tensor(), at::Tensor()};
    const auto saved = ctx->get_saved_variables();
    const at::Tensor &fa = saved[0], &fb = saved[1], &wf = saved[2];
    const int64_t V = fa.size(0), C = fa.size(1), P = fa.size(2) * fa.size(3);
    const at::Tensor scale = (grads[0].to(at::kFloat) / double(P)).contiguous();  // d mean / d pixel
    const auto cl = at::MemoryFormat::ChannelsLast;
    at::Tensor ga = at::empty_like(fa, fa.options().memory_format(cl));
    at::Tensor gb = ctx->needs_input_grad(1) ? at::empty_like(fb, fb.options().memory_format(cl)) : at::Tensor();
    cuda::launch_lpips_tap_backward(fa.data_ptr(), fb.data_ptr(), wf.data_ptr<float>(), scale.data_ptr<float>(),
                                    ga.data_ptr(), gb.defined() ? gb.data_ptr() : nullptr, V * P, P, C,
                                    at::cuda::getCurrentCUDAStream());
    return {ctx->needs_input_grad(0) ? ga : at::Tensor(), gb, at::Tensor()};
  }
};
#endif

}  // namespace

bool lpips_tap_fused(const at::Tensor& fa, const at::Tensor& fb) {
#if FLAT_WITH_CUDA
  auto ok = [](const at::Tensor& f) {
    return f.is_cuda() && f.scalar_type() == at::kBFloat16 && f.dim() == 4 &&
           f.is_contiguous(at::MemoryFormat::ChannelsLast) && reinterpret_cast<uintptr_t>(f.data_ptr()) % 16 == 0;
  };
  return ok(fa) && ok(fb) && fa.sizes() == fb.sizes() && cuda::lpips_tap_supported(fa.size(1));
#else
  (void)fa;
  (void)fb;
  return false;
#endif
}

at::Tensor lpips_tap_distance(const at::Tensor& fa, const at::Tensor& fb, const at::Tensor& w) {
  FLAT_CHECK(fa.dim() == 4 && fa.sizes() == fb.sizes() && w.numel() == fa.size(1),
             "lpips: tap features " + shape_str(fa) + " and " + shape_str(fb) + " with " +
                 std::to_string(w.numel()) + " lin weights do not match");
#if FLAT_WITH_CUDA
  if (lpips_tap_fused(fa, fb)) return LpipsTapFunction::apply(fa, fb, w.detach());
#endif
  return aten_tap_distance(fa, fb, w);
}

}  // namespace flat::loss
