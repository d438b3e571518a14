#include "flat/model/resample.h"

#include <cmath>
#include <mutex>

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/model/conv3d_inference.h"

namespace flat::model {
namespace {

// The four phase filters of upsample_conv_subpixel, (4*O, I, 1, 2, 2), and the
// bias repeated for them.
std::pair<at::Tensor, at::Tensor> subpixel_filters(const at::Tensor& w, const at::Tensor& bias,
                                                   at::MemoryFormat format) {
  const int64_t O = w.size(0), I = w.size(1);
  at::Tensor R = torch::tensor({1.f, 0.f, 0.f, 0.f, 1.f, 1.f, 1.f, 1.f, 0.f, 0.f, 0.f, 1.f},
                               w.options().dtype(at::kFloat)).view({2, 2, 3});  // (parity, tap, original tap)
  at::Tensor K = at::einsum("apy,oiyx,bqx->aboipq", {R, w.to(at::kFloat), R}).to(w.scalar_type());
  return {K.reshape({4 * O, I, 1, 2, 2}).contiguous(format), bias.repeat({4})};
}

// Nearest x2 followed by a 3x3 conv (pad 1) equals, for each output parity
// (a, b), a 2x2 conv of the low-resolution input with summed taps: rows
// (y-1, y, y+1) of the upsampled image are input rows (i-1, i, i) for a = 0 and
// (i, i, i+1) for a = 1. All four phases run as ONE conv with 4*O outputs and
// padding 1 (so (H+1) x (W+1) positions); phase (a, b) is the window starting
// at (a, b). 4/9 of the multiply-adds, and the 4x larger upsampled tensor is
// never materialised.
at::Tensor upsample_conv_subpixel(const at::Tensor& x, const at::Tensor& weight, const at::Tensor& bias4,
                                  const std::string& backend) {
  const int64_t B = x.size(0), T = x.size(2), H = x.size(3), W = x.size(4);
  const int64_t O = weight.size(0) / 4;
  at::Tensor y = conv3d_inference(x, weight, bias4, {0, 1, 1}, {}, backend);  // (B,4O,T,H+1,W+1)
  at::Tensor out = at::empty({B, O, T, 2 * H, 2 * W}, x.options().memory_format(x.suggest_memory_format()));
  at::Tensor phases = out.unflatten(4, {W, 2}).unflatten(3, {H, 2});  // (B,O,T,H,2,W,2)
  for (int64_t a = 0; a < 2; ++a) {
    for (int64_t b = 0; b < 2; ++b) {
      phases.select(6, b).select(4, a).copy_(y.narrow(1, (2 * a + b) * O, O).narrow(3, a, H).narrow(4, b, W));
    }
  }
  return out;
}
}  // namespace

ResampleImpl::ResampleImpl(int64_t channels, ResampleMode mode, const KernelChoices& kernels)
    : mode_(mode), subpixel_(kernels.subpixel_upsample), conv_backend_(kernels.conv_backend) {
  check_conv_backend(conv_backend_);
  const bool down = mode == ResampleMode::downsample2d || mode == ResampleMode::downsample3d;
  const int64_t out = down ? channels : channels / 2;
  FLAT_CHECK(down || channels % 2 == 0, "Resample: upsampling needs an even channel count, got " +
                                            std::to_string(channels));
  auto resample = register_module("resample", std::make_shared<torch::nn::Module>());
  auto conv = std::make_shared<torch::nn::Module>();
  const double bound = 1.0 / std::sqrt(double(channels * 9));
  conv_weight = conv->register_parameter("weight", torch::empty({out, channels, 3, 3}).uniform_(-bound, bound));
  conv_bias = conv->register_parameter("bias", torch::empty({out}).uniform_(-bound, bound));
  resample->register_module("1", conv);
  if (mode == ResampleMode::upsample3d) {
    time_conv = register_module(
        "time_conv", CausalConv3d(channels, 2 * channels, Int3{3, 1, 1}, Int3{1, 1, 1}, Int3{1, 0, 0}, conv_backend_));
  } else if (mode == ResampleMode::downsample3d) {
    time_conv = register_module(
        "time_conv", CausalConv3d(channels, channels, Int3{3, 1, 1}, Int3{2, 1, 1}, Int3{0, 0, 0}, conv_backend_));
  }
}

at::Tensor ResampleImpl::spatial(const at::Tensor& x) const {
  // Per-frame Conv2d == Conv3d with a (1,3,3) kernel on the 5-D tensor (no reshapes).
  const at::Tensor w = conv_weight.unsqueeze(2);
  switch (mode_) {
    case ResampleMode::upsample2d:
    case ResampleMode::upsample3d: {
      if (subpixel_) {
        const auto format = x.suggest_memory_format();
        // (Inference tensors have no version counter: no cache for them.)
        if ((at::GradMode::is_enabled() && (conv_weight.requires_grad() || conv_bias.requires_grad())) ||
            conv_weight.is_inference() || conv_bias.is_inference()) {
          const auto [weight, bias4] = subpixel_filters(conv_weight, conv_bias, format);
          return upsample_conv_subpixel(x, weight, bias4, conv_backend_);
        }
        // Without autograd the phase filters are built once per weight
        // version, dtype, device and layout (each build syncs on a tiny
        // host-to-device copy; streaming would pay it every chunk).
        const auto key = std::make_tuple(conv_weight.data_ptr(), conv_weight._version(), conv_bias._version(),
                                         conv_weight.scalar_type(), format);
        at::Tensor weight, bias4;
        {
          const std::lock_guard<std::mutex> lock(subpixel_cache_.mutex);
          if (!subpixel_cache_.weight.defined() || subpixel_cache_.key != key) {
            std::tie(subpixel_cache_.weight, subpixel_cache_.bias) = subpixel_filters(conv_weight, conv_bias, format);
            subpixel_cache_.key = key;
          }
          weight = subpixel_cache_.weight;
          bias4 = subpixel_cache_.bias;
        }
        return upsample_conv_subpixel(x, weight, bias4, conv_backend_);
      }
      // Nearest x2 is exact in any dtype (the reference's fp32 detour changes nothing).
      const std::vector<int64_t> size{x.size(2), 2 * x.size(3), 2 * x.size(4)};
      at::Tensor up = at::upsample_nearest3d(x, at::IntArrayRef(size), std::optional<double>(),
                                             std::optional<double>(), std::optional<double>());
      return at::conv3d(up, w, conv_bias, {1, 1, 1}, {0, 1, 1});
    }
    case ResampleMode::conv_only:
      return conv3d_inference(x, w.contiguous(x.suggest_memory_format()), conv_bias, {0, 1, 1}, {}, conv_backend_);
    case ResampleMode::downsample2d:
    case ResampleMode::downsample3d: {
      at::Tensor padded = at::constant_pad_nd(x, {0, 1, 0, 1});  // right and bottom (ZeroPad2d(0,1,0,1))
      return at::conv3d(padded, w, conv_bias, {1, 2, 2}, {0, 0, 0});
    }
  }
  return x;
}

void ResampleImpl::interleave_into(at::Tensor out, const at::Tensor& y) const {
  // y (B,2C,T,H,W) viewed as (B,2,C,T,H,W): channels [0:C] -> frame 2t, [C:2C] -> frame 2t+1.
  // Written straight into `out` (B,C,2T,H,W) with two strided copies (no stack + cat).
  const int64_t B = y.size(0), C = y.size(1) / 2, T = y.size(2), H = y.size(3), W = y.size(4);
  at::Tensor halves = y.view({B, 2, C, T, H, W});
  at::Tensor pairs = out.unflatten(2, {T, 2});  // (B,C,T,2,H,W)
  pairs.select(3, 0).copy_(halves.select(1, 0));
  pairs.select(3, 1).copy_(halves.select(1, 1));
}

at::Tensor ResampleImpl::upsample_time(const at::Tensor& x, bool pass_first, at::Tensor* history) {
  const int64_t B = x.size(0), C = x.size(1), T = x.size(2), H = x.size(3), W = x.size(4);
  const int64_t first = pass_first ? 1 : 0;
  at::Tensor out = at::empty({B, C, first + 2 * (T - first), H, W}, x.options().memory_format(x.suggest_memory_format()));
  if (pass_first) out.narrow(2, 0, 1).copy_(x.narrow(2, 0, 1));
  if (T > first) {
    at::Tensor rest = x.narrow(2, first, T - first);
    at::Tensor y = history ? time_conv->forward_cached(rest, *history) : time_conv->forward(rest);
    interleave_into(out.narrow(2, first, 2 * (T - first)), y);
  }
  return out;
}

at::Tensor ResampleImpl::forward(const at::Tensor& x, StreamCache* cache) {
  FLAT_CHECK(x.dim() == 5 && x.size(1) == conv_weight.size(1),
             "Resample: expected (B," + std::to_string(conv_weight.size(1)) + ",T,H,W), got " + shape_str(x));
  if (mode_ == ResampleMode::upsample3d) {
    // Full sequence: frame 0 passes; time_conv sees frames 1.. with 2 zero frames of history.
    if (cache == nullptr) return spatial(upsample_time(x, /*pass_first=*/true, nullptr));
    at::Tensor& history = cache->next();
    if (!history.defined()) {
      // First chunk: frame 0 is not doubled; the next chunk starts from zero history.
      history = at::zeros({x.size(0), x.size(1), 2, x.size(3), x.size(4)}, x.options());
      return spatial(upsample_time(x, /*pass_first=*/true, &history));
    }
    return spatial(upsample_time(x, /*pass_first=*/false, &history));
  }
  if (mode_ == ResampleMode::downsample3d) {
    at::Tensor y = spatial(x);
    if (cache == nullptr) {
      if (y.size(2) < 3) return y.narrow(2, 0, 1);
      return at::cat({y.narrow(2, 0, 1), time_conv->forward(y)}, 2);
    }
    at::Tensor& history = cache->next();
    if (!history.defined()) {
      FLAT_CHECK(y.size(2) == 1, "Resample(downsample3d): the first streaming chunk must hold 1 frame, got " +
                                     shape_str(x));
      history = y.clone();
      return y;
    }
    at::Tensor extended = at::cat({history, y}, 2);
    history = y.narrow(2, y.size(2) - 1, 1).clone();
    return time_conv->forward_prepadded(extended);
  }
  return spatial(x);
}

}  // namespace flat::model
