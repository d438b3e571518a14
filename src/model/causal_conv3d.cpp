#include "flat/model/causal_conv3d.h"

#include <cmath>

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/model/conv3d_inference.h"

namespace flat::model {

at::Tensor pad_past_frames(const at::Tensor& x, int64_t n) {
  if (n == 0) return x;
  auto sizes = x.sizes().vec();
  sizes[2] += n;
  at::Tensor out = at::empty(sizes, x.options().memory_format(x.suggest_memory_format()));
  out.narrow(2, 0, n).zero_();
  out.narrow(2, n, x.size(2)).copy_(x);
  return out;
}

CausalConv3dImpl::CausalConv3dImpl(int64_t in_channels, int64_t out_channels, Int3 kernel, Int3 stride,
                                   Int3 padding, std::string conv_backend)
    : stride_(stride), padding_(padding), conv_backend_(std::move(conv_backend)) {
  FLAT_CHECK(in_channels > 0 && out_channels > 0, "CausalConv3d: channel counts must be positive");
  check_conv_backend(conv_backend_);
  weight = register_parameter("weight", torch::empty({out_channels, in_channels, kernel[0], kernel[1], kernel[2]}));
  bias = register_parameter("bias", torch::empty({out_channels}));
  reset_parameters();
}

void CausalConv3dImpl::reset_parameters(bool zero) {
  torch::NoGradGuard no_grad;
  if (zero) {
    weight.zero_();
    bias.zero_();
    return;
  }
  // PyTorch's Conv default: kaiming_uniform(a=sqrt(5)) == U(-1/sqrt(fan_in), 1/sqrt(fan_in)).
  const double bound = 1.0 / std::sqrt(double(weight[0].numel()));
  weight.uniform_(-bound, bound);
  bias.uniform_(-bound, bound);
}

at::Tensor CausalConv3dImpl::forward_prepadded(const at::Tensor& x_padded, const at::Tensor& residual) {
  FLAT_CHECK(x_padded.dim() == 5 && x_padded.size(1) == in_channels(),
             "CausalConv3d: expected input (B," + std::to_string(in_channels()) + ",T,H,W), got " +
                 shape_str(x_padded));
  if (stride_ == Int3{1, 1, 1}) {
    return conv3d_inference(x_padded, weight, bias, {0, padding_[1], padding_[2]}, residual, conv_backend_);
  }
  at::Tensor y = at::conv3d(x_padded, weight, bias, {stride_[0], stride_[1], stride_[2]}, {0, padding_[1], padding_[2]});
  return residual.defined() ? y + residual : y;
}

at::Tensor CausalConv3dImpl::forward_single_frame(const at::Tensor& x, const at::Tensor& residual) {
  FLAT_CHECK(x.dim() == 5 && x.size(1) == in_channels() && x.size(2) == 1,
             "CausalConv3d: the single-frame path takes (B," + std::to_string(in_channels()) + ",1,H,W), got " +
                 shape_str(x));
  FLAT_CHECK(has_single_frame_path(), "CausalConv3d: no single-frame path for a kernel of " +
                                          std::to_string(weight.size(2)) + " frames with " +
                                          std::to_string(past_frames()) + " past frames and time stride " +
                                          std::to_string(stride_[0]));
  const int64_t kt = weight.size(2);
  at::Tensor y = at::conv3d(x, weight.narrow(2, kt - 1, 1), bias, {1, stride_[1], stride_[2]},
                            {0, padding_[1], padding_[2]});
  return residual.defined() ? y + residual : y;
}

at::Tensor CausalConv3dImpl::forward(const at::Tensor& x) {
  if (x.dim() == 5 && x.size(2) == 1 && has_single_frame_path()) return forward_single_frame(x);
  return forward_prepadded(pad_past_frames(x, past_frames()));
}

at::Tensor CausalConv3dImpl::forward_cached(const at::Tensor& x, at::Tensor& history) {
  const int64_t n = past_frames();
  if (n == 0) return forward_prepadded(x);  // 1x1x1 convs have no past
  at::Tensor padded;
  if (history.defined()) {
    padded = at::cat({history, x}, 2);
  } else {
    padded = pad_past_frames(x, n);
  }
  history = padded.narrow(2, padded.size(2) - n, n).clone();
  return forward_prepadded(padded);
}

}  // namespace flat::model
