// The Wan 2.1 video VAE (../shared/docs/wan_vae.md): encoder, the 1x1x1 `conv1`
// (2*z_dim -> 2*z_dim, after the encoder), `conv2` (z_dim -> z_dim, before the
// decoder), decoder. Parameter names are the original checkpoint's
// (weights.h maps the diffusers names onto them).
//
// Frame arithmetic: F = 1 + 4k video frames <-> T' = 1 + k latent frames.
// Latents crossing this API are NORMALISED: z_n = (mu - mean) / std.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>
#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "flat/model/causal_conv3d.h"
#include "flat/model/decoder3d.h"
#include "flat/model/encoder3d.h"
#include "flat/model/kernel_choices.h"
#include "flat/model/wan_vae_config.h"

namespace flat::model {

// Per-channel latent statistics of Wan 2.1 (16 values each), shaped (1,16,1,1,1).
at::Tensor latent_mean(const at::TensorOptions& options = {});
at::Tensor latent_std(const at::TensorOptions& options = {});
// z_n = (mu - mean) / std and its inverse. Needs z_dim == 16.
at::Tensor normalise_latent(const at::Tensor& mu);
at::Tensor denormalise_latent(const at::Tensor& z_n);

// Frame counts: video frames for T' latent frames (1 + 4(T'-1)), and the latent
// frames of a 1+4k video (throws naming `what` when F is not 1+4k).
int64_t video_frames(int64_t latent_frames);
int64_t latent_frames(int64_t video_frames, const std::string& what);

// The base width `dim` of the VAE (or VAE decoder) in a weights file, read
// from its header alone: encoder.conv1 (dim,3,..) or decoder.conv1
// (dim*dim_mult.back(),16,..), either naming. Throws naming the file when it
// holds neither.
int64_t vae_dim_of_file(const std::string& path, const WanVAEConfig& like = {});

class WanVAEImpl : public torch::nn::Module {
 public:
  // kernels: the implementations its norms, convs and upsamples use (the
  // scene decoder's config holds them: SceneDecoderConfig::kernels).
  explicit WanVAEImpl(const WanVAEConfig& config = {}, const KernelChoices& kernels = {});

  // video (B,3,F,H,W) in [-1,1], F = 1+4k, H and W multiples of 8 ->
  // normalised mu (B,z_dim,1+k,H/8,W/8). Streaming: chunks of 1, 4, 4, ... frames.
  at::Tensor encode(const at::Tensor& video, bool streaming = true);
  // Normalised latent (B,z_dim,T',h,w) -> video (B,3,1+4(T'-1),8h,8w), clamped to
  // [-1,1] like the reference unless clamp = false. Streaming: one latent frame at a time.
  at::Tensor decode(const at::Tensor& latent, bool streaming = true, bool clamp = true);
  // The encoder's raw output after conv1: (B,2*z_dim,T',h,w) = (mu, log_var), not normalised.
  at::Tensor encode_moments(const at::Tensor& video, bool streaming = true);

  const WanVAEConfig& config() const { return config_; }

  // Re-parameterises conv1 (its mu and log-variance rows) and conv2 so that
  // normalising with Wan 2.1's constants (normalise_latent) equals
  // normalising this VAE's raw mu with `mean` and `std` ((16,) each, measured
  // on data): mu' = (mu - mean) / std * wan_std + wan_mean, and conv2 undoes
  // it. encode() then gives latents of zero mean and unit spread per channel,
  // decode() of them the same video, and the file stays a plain Wan 2.1 VAE
  // that every tool reads unchanged. Exact up to float rounding.
  void fold_latent_statistics(const at::Tensor& mean, const at::Tensor& std);

  Encoder3d encoder{nullptr};
  CausalConv3d conv1{nullptr};  // 1x1x1, after the encoder
  CausalConv3d conv2{nullptr};  // 1x1x1, before the decoder
  Decoder3d decoder{nullptr};

 private:
  WanVAEConfig config_;
};
TORCH_MODULE(WanVAE);

}  // namespace flat::model
