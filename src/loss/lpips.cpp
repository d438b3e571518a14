// LPIPS (VGG) network, weight loading and checkpointed chunked evaluation.
// Constants and layer layout: include/flat/loss/lpips.h, docs/losses.md.
#include "flat/loss/lpips.h"

#include <filesystem>

#include <c10/core/impl/LocalDispatchKeySet.h>
#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/safetensors.h"
#include "flat/core/shape.h"
#include "flat/core/tensor_io.h"
#include "loss/lpips_tap_distance.h"

namespace flat::loss {
namespace {

// torchvision VGG16 `features`: conv index, channels in, channels out; 'M' pools
// sit after indices 3, 8, 15, 22 (i.e. after each tap but the last).
struct ConvSpec {
  int index, cin, cout;
  bool tap_after;  // relu1_2, relu2_2, relu3_3, relu4_3, relu5_3
};
const ConvSpec kVgg[] = {{0, 3, 64, false},    {2, 64, 64, true},     {5, 64, 128, false},
                         {7, 128, 128, true},  {10, 128, 256, false}, {12, 256, 256, false},
                         {14, 256, 256, true}, {17, 256, 512, false}, {19, 512, 512, false},
                         {21, 512, 512, true}, {24, 512, 512, false}, {26, 512, 512, false},
                         {28, 512, 512, true}};
const int64_t kTapChannels[] = {64, 128, 256, 512, 512};

}  // namespace

const std::vector<LpipsTensorSpec>& lpips_tensor_specs() {
  static const std::vector<LpipsTensorSpec> specs = [] {
    std::vector<LpipsTensorSpec> s;
    for (const auto& c : kVgg) {
      const std::string base = "features." + std::to_string(c.index);
      s.push_back({base + ".weight", {c.cout, c.cin, 3, 3}});
      s.push_back({base + ".bias", {c.cout}});
    }
    for (int k = 0; k < 5; ++k) s.push_back({"lin" + std::to_string(k) + ".weight", {1, kTapChannels[k], 1, 1}});
    return s;
  }();
  return specs;
}

void check_lpips_file(const std::string& path) {
  const std::string hint = " (docs/losses.md explains how to make this file)";
  FLAT_CHECK(!path.empty(), "LPIPS weights: no file configured (loss.lpips_weights)" + hint);
  FLAT_CHECK(std::filesystem::is_regular_file(path), "LPIPS weights file '" + path + "' not found" + hint);
  auto file = safetensors::MappedFile::open(path);
  for (const auto& spec : lpips_tensor_specs()) {
    const auto* entry = file->header().find(spec.name);
    FLAT_CHECK(entry != nullptr, "LPIPS weights file '" + path + "': missing tensor '" + spec.name +
                                     "' of shape " + shape_str(spec.shape) + hint);
    FLAT_CHECK(entry->shape == spec.shape, "LPIPS weights file '" + path + "': tensor '" + spec.name +
                                               "' has shape " + shape_str(entry->shape) + ", expected " +
                                               shape_str(spec.shape));
    const auto dt = entry->dtype;
    FLAT_CHECK(dt == safetensors::DType::F32 || dt == safetensors::DType::F16 ||
                   dt == safetensors::DType::BF16 || dt == safetensors::DType::F64,
               "LPIPS weights file '" + path + "': tensor '" + spec.name + "' has dtype " +
                   std::string(safetensors::dtype_name(dt)) + ", expected a float type");
  }
}

LpipsImpl::LpipsImpl() {
  for (const auto& c : kVgg) {
    convs_.push_back(register_module("features_" + std::to_string(c.index),
                                     torch::nn::Conv2d(torch::nn::Conv2dOptions(c.cin, c.cout, 3).padding(1))));
  }
  for (int k = 0; k < 5; ++k) {
    lins_.push_back(register_module("lin" + std::to_string(k),
                                    torch::nn::Conv2d(torch::nn::Conv2dOptions(kTapChannels[k], 1, 1).bias(false))));
  }
  torch::NoGradGuard no_grad;
  for (auto& conv : convs_) torch::nn::init::kaiming_normal_(conv->weight, 0.0, torch::kFanIn, torch::kReLU);
  for (auto& lin : lins_) lin->weight.uniform_(0.0, 1.0 / double(lin->weight.size(1)));
  shift_ = register_buffer("shift", torch::tensor({-.030, -.088, -.188}).view({1, 3, 1, 1}));
  scale_ = register_buffer("scale", torch::tensor({.458, .448, .450}).view({1, 3, 1, 1}));
  for (auto& p : parameters()) p.set_requires_grad(false);  // a fixed metric
}

void LpipsImpl::load(const std::string& path) {
  check_lpips_file(path);
  auto file = safetensors::MappedFile::open(path);
  torch::NoGradGuard no_grad;
  size_t i = 0;
  for (size_t c = 0; c < convs_.size(); ++c) {
    const auto& specs = lpips_tensor_specs();
    convs_[c]->weight.copy_(read_tensor(*file, specs[i++].name));
    convs_[c]->bias.copy_(read_tensor(*file, specs[i++].name));
  }
  for (int k = 0; k < 5; ++k) lins_[k]->weight.copy_(read_tensor(*file, "lin" + std::to_string(k) + ".weight"));
  bf16_weights_.clear();
}

std::vector<LpipsImpl::ConvWeights> LpipsImpl::conv_weights(bool bf16) {
  std::vector<ConvWeights> w;
  if (!bf16) {
    for (auto& conv : convs_) w.push_back({conv->weight, conv->bias});
    return w;
  }
  // The copy follows the parameters to another device.
  if (bf16_weights_.empty() || bf16_weights_[0].weight.device() != convs_[0]->weight.device()) {
    torch::NoGradGuard no_grad;
    const bool cuda = convs_[0]->weight.is_cuda();
    bf16_weights_.clear();
    for (auto& conv : convs_) {
      auto weight = conv->weight.to(at::kBFloat16);
      if (cuda) weight = weight.contiguous(at::MemoryFormat::ChannelsLast);
      bf16_weights_.push_back({weight, conv->bias.to(at::kBFloat16)});
    }
  }
  return bf16_weights_;
}

std::vector<at::Tensor> LpipsImpl::taps(const at::Tensor& x, bool bf16) {
  // Explicit dtypes: an enclosing autocast would otherwise pick them, and the
  // backward's recomputation (on autograd's thread) runs without it.
  c10::impl::ExcludeDispatchKeyGuard no_autocast(c10::autocast_dispatch_keyset);
  const auto dtype = convs_[0]->weight.scalar_type();
  const auto w = conv_weights(bf16);
  auto h = (x.to(dtype) * 2 - 1 - shift_.to(dtype)) / scale_.to(dtype);
  if (bf16) h = h.to(at::kBFloat16);
  if (bf16 && h.is_cuda()) h = h.contiguous(at::MemoryFormat::ChannelsLast);
  std::vector<at::Tensor> out;
  for (size_t c = 0; c < w.size(); ++c) {
    h = at::conv2d(h, w[c].weight, w[c].bias, 1, 1).relu_();
    if (!kVgg[c].tap_after) continue;
    out.push_back(h);  // raw: distance() normalises them (lpips_tap_distance)
    if (out.size() < 5) h = at::max_pool2d(h, {2, 2}, {2, 2});
  }
  return out;
}

at::Tensor LpipsImpl::distance(const std::vector<at::Tensor>& fa, const std::vector<at::Tensor>& fb) {
  FLAT_CHECK(fa.size() == 5 && fb.size() == 5, "lpips: expected 5 tap features per image batch");
  c10::impl::ExcludeDispatchKeyGuard no_autocast(c10::autocast_dispatch_keyset);  // as in taps()
  at::Tensor total;
  for (size_t k = 0; k < 5; ++k) {
    auto d = lpips_tap_distance(fa[k], fb[k], lins_[k]->weight);
    total = total.defined() ? total + d : d;
  }
  return total;
}

at::Tensor LpipsImpl::forward(const at::Tensor& a, const at::Tensor& b) {
  check_shape(a, {-1, 3, -1, -1}, "lpips: first image batch", "(V,3,H,W)");
  FLAT_CHECK(a.sizes() == b.sizes(), "lpips: image shapes differ: " + shape_str(a) + " vs " + shape_str(b));
  FLAT_CHECK(a.size(2) >= 16 && a.size(3) >= 16, "lpips: images must be at least 16x16, got " + shape_str(a));
  // Both batches through VGG at once.
  const int64_t V = a.size(0);
  const auto dtype = convs_[0]->weight.scalar_type();
  auto f = taps(at::cat({a.to(dtype), b.to(dtype)}, 0), /*bf16=*/false);
  std::vector<at::Tensor> fa, fb;
  for (const auto& t : f) {
    fa.push_back(t.narrow(0, 0, V));
    fb.push_back(t.narrow(0, V, V));
  }
  return distance(fa, fb);
}

namespace {

std::vector<at::Tensor> taps_without_grad(LpipsImpl& net, const at::Tensor& x, bool bf16) {
  torch::NoGradGuard no_grad;
  return net.taps(x, bf16);
}

// One chunk through LPIPS without keeping VGG activations: forward under
// no-grad, backward re-runs the chunk with grad and differentiates it. A
// target that needs no gradient is recomputed without grad (nothing kept).
struct LpipsCheckpoint : public torch::autograd::Function<LpipsCheckpoint> {
  static at::Tensor forward(torch::autograd::AutogradContext* ctx, const at::Tensor& a, const at::Tensor& b,
                            LpipsImpl* net, bool bf16) {
    ctx->save_for_backward({a, b});
    ctx->saved_data["net"] = reinterpret_cast<int64_t>(net);  // the caller's module outlives the graph
    ctx->saved_data["bf16"] = bf16;
    torch::NoGradGuard no_grad;
    return net->distance(net->taps(a, bf16), net->taps(b, bf16));
  }
  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grad_out) {
    auto saved = ctx->get_saved_variables();
    auto* net = reinterpret_cast<LpipsImpl*>(ctx->saved_data["net"].toInt());
    const bool bf16 = ctx->saved_data["bf16"].toBool();
    const bool need_a = ctx->needs_input_grad(0), need_b = ctx->needs_input_grad(1);
    torch::AutoGradMode enable(true);
    auto a = saved[0].detach().requires_grad_(need_a);
    auto b = saved[1].detach().requires_grad_(need_b);
    auto fb = need_b ? net->taps(b, bf16) : taps_without_grad(*net, b, bf16);
    auto d = net->distance(net->taps(a, bf16), fb);
    std::vector<at::Tensor> inputs;
    if (need_a) inputs.push_back(a);
    if (need_b) inputs.push_back(b);
    auto grads = torch::autograd::grad({d}, inputs, {grad_out[0]});
    at::Tensor ga = need_a ? grads[0] : at::Tensor();
    at::Tensor gb = need_b ? grads[need_a ? 1 : 0] : at::Tensor();
    return {ga, gb, at::Tensor(), at::Tensor()};
  }
};

at::Tensor resize_longer_side(const at::Tensor& x, int64_t max_size) {
  const int64_t H = x.size(2), W = x.size(3);
  if (max_size <= 0 || std::max(H, W) <= max_size) return x;
  const double f = double(max_size) / double(std::max(H, W));
  const int64_t h = std::max<int64_t>(1, std::lround(H * f)), w = std::max<int64_t>(1, std::lround(W * f));
  namespace F = torch::nn::functional;
  return F::interpolate(x, F::InterpolateFuncOptions()
                               .size(std::vector<int64_t>{h, w})
                               .mode(torch::kBilinear)
                               .align_corners(false)
                               .antialias(true));
}

}  // namespace

at::Tensor lpips_distance(Lpips& net, const at::Tensor& a, const at::Tensor& b, const LpipsOptions& o) {
  check_shape(a, {-1, 3, -1, -1}, "lpips: rendered images", "(V,3,H,W)");
  FLAT_CHECK(a.sizes() == b.sizes(), "lpips: image shapes differ: " + shape_str(a) + " vs " + shape_str(b));
  FLAT_CHECK(o.chunk > 0, "lpips: chunk must be positive");
  auto ra = resize_longer_side(a, o.max_size), rb = resize_longer_side(b, o.max_size);
  FLAT_CHECK(ra.size(2) >= 16 && ra.size(3) >= 16, "lpips: images must be at least 16x16, got " + shape_str(ra));
  const bool grad_mode = at::GradMode::is_enabled();
  const bool grad = grad_mode && (ra.requires_grad() || rb.requires_grad());
  std::vector<at::Tensor> parts;
  for (int64_t start = 0; start < a.size(0); start += o.chunk) {
    const int64_t n = std::min(o.chunk, a.size(0) - start);
    auto ca = ra.narrow(0, start, n), cb = rb.narrow(0, start, n);
    if (grad && o.checkpoint) {
      parts.push_back(LpipsCheckpoint::apply(ca, cb, net.get(), o.bf16));
      continue;
    }
    // The target's taps once, without grad, unless it needs a gradient itself.
    auto fb = grad_mode && cb.requires_grad() ? net->taps(cb, o.bf16) : taps_without_grad(*net, cb, o.bf16);
    parts.push_back(net->distance(net->taps(ca, o.bf16), fb));
  }
  return at::cat(parts, 0);
}

}  // namespace flat::loss
