#include "flat/model/rms_norm.h"

#include <cmath>

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"

#if FLAT_WITH_CUDA
#include <ATen/cuda/CUDAContext.h>
#include <torch/csrc/autograd/custom_function.h>

#include "model/cuda/rms_norm_silu_kernel.h"
#endif

namespace flat::model {
namespace {

// The normalisation factor sqrt(C) / max(||x||, 1e-12) over dim 1, in fp32.
at::Tensor inverse_norm(const at::Tensor& x) {
  const double scale = std::sqrt(double(x.size(1)));
  const auto dtype = x.scalar_type() == at::kDouble ? at::kDouble : at::kFloat;  // never below fp32
  return at::linalg_vector_norm(x, 2, {1}, /*keepdim=*/true, dtype).clamp_min(1e-12).reciprocal().mul(scale);
}

at::Tensor gamma_like(const at::Tensor& gamma, const at::Tensor& x) {
  std::vector<int64_t> shape(x.dim(), 1);
  shape[1] = gamma.numel();
  return gamma.reshape(shape);
}

// A (B,C,n+T,H,W) tensor for the result of x (B,C,T,H,W) whose first n
// frames are `history` (zeros when undefined); frames n.. are left to fill.
at::Tensor padded_output(const at::Tensor& x, int64_t n, const at::Tensor& history, at::MemoryFormat format) {
  at::Tensor out = at::empty({x.size(0), x.size(1), n + x.size(2), x.size(3), x.size(4)}, x.options().memory_format(format));
  if (n > 0) {
    if (history.defined()) {
      FLAT_CHECK(history.size(2) == n, "RMS_norm+SiLU: history must hold " + std::to_string(n) + " frames, got " +
                                           shape_str(history));
      out.narrow(2, 0, n).copy_(history);
    } else {
      out.narrow(2, 0, n).zero_();
    }
  }
  return out;
}
}  // namespace

RMSNormImpl::RMSNormImpl(int64_t channels, bool images, bool fused) : fused_(fused) {
  FLAT_CHECK(channels > 0, "RMS_norm: channels must be positive");
  gamma = register_parameter("gamma", images ? torch::ones({channels, 1, 1}) : torch::ones({channels, 1, 1, 1}));
}

at::Tensor RMSNormImpl::forward(const at::Tensor& x) { return rms_norm(x, gamma); }

at::Tensor RMSNormImpl::silu_padded(const at::Tensor& x, int64_t n, const at::Tensor& history) const {
  return rms_norm_silu_padded(x, gamma, n, history, fused_);
}

at::Tensor RMSNormImpl::silu_streamed(const at::Tensor& x, int64_t n, at::Tensor& history) const {
  return rms_norm_silu_streamed(x, gamma, n, history, fused_);
}

at::Tensor rms_norm(const at::Tensor& x, const at::Tensor& gamma) {
  FLAT_CHECK(x.dim() >= 2 && x.size(1) == gamma.numel(),
             "RMS_norm: expected " + std::to_string(gamma.numel()) + " channels in dim 1, got " + shape_str(x));
  return x * inverse_norm(x).to(x.scalar_type()) * gamma_like(gamma, x);
}

bool fused_norm_eligible(const at::Tensor& x, const at::Tensor& gamma) {
#if FLAT_WITH_CUDA
  return x.is_cuda() && x.dim() == 5 && (x.scalar_type() == at::kFloat || x.scalar_type() == at::kBFloat16) &&
         at::isFloatingType(gamma.scalar_type()) && gamma.numel() == x.size(1) &&
         cuda::rms_norm_silu_supported(x.size(1));
#else
  (void)x;
  (void)gamma;
  return false;
#endif
}

bool fused_norm_available(const at::Tensor& x, const at::Tensor& gamma) {
  const bool grad = at::GradMode::is_enabled() && (x.requires_grad() || gamma.requires_grad());
  return !grad && fused_norm_eligible(x, gamma);
}

#if FLAT_WITH_CUDA
namespace {

// silu(rms_norm(x)) written into frames [n, n+T) of a new (B,C,n+T,H,W)
// channels-last tensor whose first n frames are `history` (zeros when
// undefined): the fused kernel, for a channels-last x. When history_out is
// given it receives the last n frames (written by the kernel as a second
// destination when T >= n, so no copy of them afterwards).
at::Tensor fused_norm_silu_padded(const at::Tensor& x, const at::Tensor& gamma, int64_t n, const at::Tensor& history,
                                  at::Tensor* history_out) {
  const int64_t B = x.size(0), C = x.size(1), T = x.size(2), H = x.size(3), W = x.size(4);
  const auto cl = at::MemoryFormat::ChannelsLast3d;
  at::Tensor out = padded_output(x, n, history, cl);
  at::Tensor next;
  if (history_out != nullptr && n > 0 && T >= n) next = at::empty({B, C, n, H, W}, x.options().memory_format(cl));
  const at::Tensor g = gamma.to(x.scalar_type()).contiguous();
  cuda::launch_rms_norm_silu(x.data_ptr(), g.data_ptr(), out.data_ptr(), B, T, H * W, C, n + T, n,
                             float(std::sqrt(double(C))), /*silu=*/true, x.scalar_type() == at::kBFloat16,
                             next.defined() ? next.data_ptr() : nullptr, n, at::cuda::getCurrentCUDAStream());
  if (history_out != nullptr) *history_out = next.defined() ? next : out.narrow(2, T, n).clone();
  return out;
}

// The same as one autograd node with the fused backward kernel (training):
// two passes over memory forward and three backward, where the ATen form
// takes about eight each way and a cat for the padding.
struct FusedNormSiluFunction : public torch::autograd::Function<FusedNormSiluFunction> {
  static at::Tensor forward(torch::autograd::AutogradContext* ctx, const at::Tensor& x, const at::Tensor& gamma,
                            int64_t n) {
    ctx->save_for_backward({x, gamma});
    ctx->saved_data["n"] = n;
    return fused_norm_silu_padded(x, gamma, n, {}, nullptr);
  }

  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    if (!grads[0].defined()) return {at::Tensor(), at::Tensor(), at::Tensor()};
    const auto saved = ctx->get_saved_variables();
    const at::Tensor& x = saved[0];
    const at::Tensor& gamma = saved[1];
    const int64_t n = ctx->saved_data["n"].toInt();
    const int64_t B = x.size(0), C = x.size(1), T = x.size(2), H = x.size(3), W = x.size(4);
    const at::Tensor go = grads[0].to(x.scalar_type()).contiguous(at::MemoryFormat::ChannelsLast3d);
    at::Tensor gx = at::empty_like(x, x.options().memory_format(at::MemoryFormat::ChannelsLast3d));
    const at::Tensor g = gamma.to(at::kFloat).contiguous();
    at::Tensor partials = at::empty({cuda::rms_norm_silu_backward_max_blocks(B, T, H * W), C},
                                    x.options().dtype(at::kFloat));
    const int64_t rows = cuda::launch_rms_norm_silu_backward(
        x.data_ptr(), g.data_ptr<float>(), go.data_ptr(), gx.data_ptr(), partials.data_ptr<float>(), B, T, H * W, C,
        n + T, n, float(std::sqrt(double(C))), x.scalar_type() == at::kBFloat16, at::cuda::getCurrentCUDAStream());
    at::Tensor gg = partials.narrow(0, 0, rows).sum(0).view(gamma.sizes()).to(gamma.scalar_type());
    return {gx, gg, at::Tensor()};
  }
};

}  // namespace
#endif

namespace {

// rms_norm_silu_padded, and when history_out is given, the last n frames of
// the result as the layer's next streaming history.
at::Tensor norm_silu_padded(const at::Tensor& x, const at::Tensor& gamma, int64_t n, const at::Tensor& history,
                            at::Tensor* history_out, bool fused) {
  FLAT_CHECK(x.dim() == 5 && x.size(1) == gamma.numel(),
             "RMS_norm+SiLU: expected (B," + std::to_string(gamma.numel()) + ",T,H,W), got " + shape_str(x));
  const int64_t B = x.size(0), C = x.size(1), T = x.size(2), H = x.size(3), W = x.size(4);
#if FLAT_WITH_CUDA
  if (fused && fused_norm_eligible(x, gamma)) {
    // One layout for the kernels: x is made channels-last once (a no-op
    // after the first norm: the convs keep the layout).
    const at::Tensor xc = x.contiguous(at::MemoryFormat::ChannelsLast3d);
    if (fused_norm_available(x, gamma)) return fused_norm_silu_padded(xc, gamma, n, history, history_out);
    if (history_out == nullptr && !history.defined()) return FusedNormSiluFunction::apply(xc, gamma, n);
  }
#else
  (void)fused;
#endif
  // ATen ops (the CPU, and what the kernels do not take).
  at::Tensor y = x * inverse_norm(x).to(x.scalar_type());
  y.mul_(gamma_like(gamma, x));
  auto keep_history = [&](const at::Tensor& result) {
    if (history_out != nullptr) *history_out = result.narrow(2, result.size(2) - n, n).clone();
    return result;
  };
  if (at::GradMode::is_enabled() && (x.requires_grad() || gamma.requires_grad())) {
    // Differentiable: build the padded tensor with cat (autograd tracks it).
    at::Tensor act = at::silu(y);
    if (n == 0) return act;
    at::Tensor past = history.defined() ? history : at::zeros({B, C, n, H, W}, x.options());
    return keep_history(at::cat({past, act}, 2));
  }
  at::Tensor out = padded_output(x, n, history, x.suggest_memory_format());
  at::Tensor body = out.narrow(2, n, T);
  at::silu_out(body, y);
  return keep_history(out);
}

}  // namespace

at::Tensor rms_norm_silu_padded(const at::Tensor& x, const at::Tensor& gamma, int64_t n, const at::Tensor& history,
                                bool fused) {
  return norm_silu_padded(x, gamma, n, history, nullptr, fused);
}

at::Tensor rms_norm_silu_streamed(const at::Tensor& x, const at::Tensor& gamma, int64_t n, at::Tensor& history,
                                  bool fused) {
  const at::Tensor past = history;
  return norm_silu_padded(x, gamma, n, past, &history, fused);
}

}  // namespace flat::model
