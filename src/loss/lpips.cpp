// LPIPS (VGG) network, weight loading and checkpointed chunked evaluation.
// Constants and layer layout: include/flat/loss/lpips.h, docs/losses.md.
#include "flat/loss/lpips.h"

#include <filesystem>

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/safetensors.h"
#include "flat/core/shape.h"
#include "flat/core/tensor_io.h"

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
}

at::Tensor LpipsImpl::features_distance(const at::Tensor& a, const at::Tensor& b) {
  const int64_t V = a.size(0);
  // Both images through VGG at once.
  auto x = (at::cat({a, b}, 0) * 2 - 1 - shift_.to(a.dtype())) / scale_.to(a.dtype());
  at::Tensor total = at::zeros({V}, a.options());
  int tap = 0;
  for (size_t c = 0; c < convs_.size(); ++c) {
    x = at::relu(convs_[c]->forward(x));
    if (!kVgg[c].tap_after) continue;
    auto f = x / (x.square().sum(1, true).sqrt() + 1e-10);
    auto diff = (f.narrow(0, 0, V) - f.narrow(0, V, V)).square();
    total = total + lins_[tap]->forward(diff).mean({1, 2, 3});
    ++tap;
    if (tap < 5) x = at::max_pool2d(x, {2, 2}, {2, 2});
  }
  return total;
}

at::Tensor LpipsImpl::forward(const at::Tensor& a, const at::Tensor& b) {
  check_shape(a, {-1, 3, -1, -1}, "lpips: first image batch", "(V,3,H,W)");
  FLAT_CHECK(a.sizes() == b.sizes(), "lpips: image shapes differ: " + shape_str(a) + " vs " + shape_str(b));
  FLAT_CHECK(a.size(2) >= 16 && a.size(3) >= 16, "lpips: images must be at least 16x16, got " + shape_str(a));
  auto w = convs_[0]->weight;
  return features_distance(a.to(w.dtype()), b.to(w.dtype()));
}

namespace {

// One chunk through LPIPS without keeping VGG activations: forward under
// no-grad, backward re-runs the chunk with grad and differentiates it.
struct LpipsCheckpoint : public torch::autograd::Function<LpipsCheckpoint> {
  static at::Tensor forward(torch::autograd::AutogradContext* ctx, const at::Tensor& a, const at::Tensor& b,
                            LpipsImpl* net) {
    ctx->save_for_backward({a, b});
    ctx->saved_data["net"] = reinterpret_cast<int64_t>(net);  // the caller's module outlives the graph
    torch::NoGradGuard no_grad;
    return net->forward(a, b);
  }
  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grad_out) {
    auto saved = ctx->get_saved_variables();
    auto* net = reinterpret_cast<LpipsImpl*>(ctx->saved_data["net"].toInt());
    const bool need_a = ctx->needs_input_grad(0), need_b = ctx->needs_input_grad(1);
    torch::AutoGradMode enable(true);
    auto a = saved[0].detach().requires_grad_(need_a);
    auto b = saved[1].detach().requires_grad_(need_b);
    auto d = net->forward(a, b);
    std::vector<at::Tensor> inputs;
    if (need_a) inputs.push_back(a);
    if (need_b) inputs.push_back(b);
    auto grads = torch::autograd::grad({d}, inputs, {grad_out[0]});
    at::Tensor ga = need_a ? grads[0] : at::Tensor();
    at::Tensor gb = need_b ? grads[need_a ? 1 : 0] : at::Tensor();
    return {ga, gb, at::Tensor()};
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

at::Tensor lpips_distance(Lpips& net, const at::Tensor& a, const at::Tensor& b, int64_t max_size, int64_t chunk) {
  check_shape(a, {-1, 3, -1, -1}, "lpips: rendered images", "(V,3,H,W)");
  FLAT_CHECK(a.sizes() == b.sizes(), "lpips: image shapes differ: " + shape_str(a) + " vs " + shape_str(b));
  FLAT_CHECK(chunk > 0, "lpips: chunk must be positive");
  auto ra = resize_longer_side(a, max_size), rb = resize_longer_side(b, max_size);
  const bool grad = at::GradMode::is_enabled() && (ra.requires_grad() || rb.requires_grad());
  std::vector<at::Tensor> parts;
  for (int64_t start = 0; start < a.size(0); start += chunk) {
    const int64_t n = std::min(chunk, a.size(0) - start);
    auto ca = ra.narrow(0, start, n), cb = rb.narrow(0, start, n);
    parts.push_back(grad ? LpipsCheckpoint::apply(ca, cb, net.get()) : net->forward(ca, cb));
  }
  return at::cat(parts, 0);
}

}  // namespace flat::loss
