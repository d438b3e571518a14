// LPIPS, VGG variant (Zhang et al. 2018, v0.1), the perceptual loss of the
// paper (Losses: lambda_perc = 0.5) and the LPIPS column of its tables.
//
//   x in [0,1] -> 2x - 1 -> (x - shift) / scale, shift = (-.030,-.088,-.188),
//   scale = (.458,.448,.450); VGG16 `features` taps after relu1_2, relu2_2,
//   relu3_3, relu4_3, relu5_3; per tap k: channel-unit-normalise (eps 1e-10),
//   squared difference, 1x1 conv lin_k (no bias, weights >= 0), spatial mean;
//   d(a, b) = sum_k.
//
// Weights come from ONE safetensors file (docs/losses.md says how to make it
// from torchvision's VGG16 and the official LPIPS v0.1 lin layers):
//   features.{0,2,5,7,10,12,14,17,19,21,24,26,28}.weight  (Cout,Cin,3,3)
//   features.{...}.bias                                    (Cout)
//   lin{0..4}.weight   (1,C,1,1), C = 64, 128, 256, 512, 512
// Network parameters never receive gradient; the inputs do.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <torch/nn/module.h>
#include <torch/nn/modules/conv.h>
#include <torch/nn/pimpl.h>

namespace flat::loss {

struct LpipsTensorSpec {
  std::string name;
  std::vector<int64_t> shape;
};
// The 31 tensors the weights file must hold, in VGG order.
const std::vector<LpipsTensorSpec>& lpips_tensor_specs();

// Checks that `path` exists and holds every tensor of lpips_tensor_specs() with
// the right shape and a floating dtype (reads only the header). Throws
// flat::Error naming the file and the missing or mis-shaped tensor.
void check_lpips_file(const std::string& path);

// How lpips_distance runs the network.
struct LpipsOptions {
  int64_t max_size = 512;             // resize the longer side to this first (0: never resize)
  int64_t chunk = 4;                  // views per pass through VGG
  bool checkpoint = true;  // grad mode: free each pass's VGG activations, recompute them in backward
  bool bf16 = false;       // convolutions in bf16 (channels-last on CUDA); else in the parameters' dtype
};

class LpipsImpl : public torch::nn::Module {
 public:
  // Random weights (He-initialised convs, non-negative lin weights): for tests
  // and for shape checks; load() replaces them.
  LpipsImpl();
  // Loads and checks the weights file (see check_lpips_file).
  void load(const std::string& path);
  // a, b: (V,3,H,W) in [0,1], H, W >= 16. Returns (V) distances, in fp32
  // (the parameters' dtype), both batches through the network at once.
  at::Tensor forward(const at::Tensor& a, const at::Tensor& b);

  // The five tap features (after relu1_2 .. relu5_3, not yet normalised) of
  // images x (V,3,H,W) in [0,1]. Convolutions in the parameters' dtype, or
  // with bf16 in a bf16 copy of the weights (channels-last on CUDA, made
  // once). The caller's autocast state does not apply.
  std::vector<at::Tensor> taps(const at::Tensor& x, bool bf16);
  // d = sum_k w_k . mean_hw (unit(fa_k) - unit(fb_k))^2: (V), unit(f) = f over
  // its channel norm (+1e-10) at each pixel. The 1x1 lin conv and the spatial
  // mean commute (both linear), so the mean is taken first. In fp32 at least
  // (fused kernels for bf16 CUDA taps: lpips_tap_distance), whatever the
  // caller's autocast state.
  at::Tensor distance(const std::vector<at::Tensor>& fa, const std::vector<at::Tensor>& fb);

 private:
  struct ConvWeights {
    at::Tensor weight, bias;
  };
  std::vector<ConvWeights> conv_weights(bool bf16);
  std::vector<torch::nn::Conv2d> convs_;  // VGG16 features convs, in order
  std::vector<torch::nn::Conv2d> lins_;   // lin0..lin4
  at::Tensor shift_, scale_;
  std::vector<ConvWeights> bf16_weights_;  // made by the first bf16 taps(), dropped by load()
};
TORCH_MODULE(Lpips);

// LPIPS of large image batches with bounded memory: images whose longer side
// exceeds o.max_size (> 0) are first resized (bilinear, antialiased, aspect
// kept) so that it equals max_size, and the V images go through the network
// o.chunk at a time. A `b` that needs no gradient (the training target) goes
// through VGG once, without grad. In grad mode with o.checkpoint each chunk's
// VGG activations are freed after its forward and recomputed in backward, so
// peak memory is that of one chunk; without, plain autograd keeps them all
// (faster: no second forward). Returns (V), fp32.
at::Tensor lpips_distance(Lpips& net, const at::Tensor& a, const at::Tensor& b, const LpipsOptions& o = {});

}  // namespace flat::loss
