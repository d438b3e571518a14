#include "flat/model/wan_vae.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/safetensors.h"
#include "flat/core/shape.h"
#include "flat/model/weights.h"

namespace flat::model {
namespace {
// Wan 2.1 latent statistics (../shared/docs/wan_vae.md, Latent normalisation).
const std::vector<float> kMean = {-0.7571f, -0.7089f, -0.9113f, 0.1075f,  -0.1745f, 0.9653f,  -0.1517f, 1.5508f,
                                  0.4134f,  -0.0715f, 0.5517f,  -0.3632f, -0.1922f, -0.9497f, 0.2503f,  -0.2921f};
const std::vector<float> kStd = {2.8184f, 1.4541f, 2.3275f, 2.6558f, 1.2196f, 1.7708f, 2.6052f, 2.0743f,
                                 3.2687f, 2.1526f, 2.8652f, 1.5579f, 1.6382f, 1.1253f, 2.8251f, 1.9160f};

at::Tensor stats(const std::vector<float>& values, const at::TensorOptions& options) {
  return torch::tensor(values, torch::kFloat).view({1, 16, 1, 1, 1}).to(options);
}
void check_latent_channels(const at::Tensor& z, const char* what) {
  FLAT_CHECK(z.dim() == 5 && z.size(1) == 16, std::string(what) +
                                                   ": the Wan 2.1 latent statistics need (B,16,T,h,w), got " +
                                                   shape_str(z));
}
}  // namespace

at::Tensor latent_mean(const at::TensorOptions& options) { return stats(kMean, options); }
at::Tensor latent_std(const at::TensorOptions& options) { return stats(kStd, options); }

at::Tensor normalise_latent(const at::Tensor& mu) {
  check_latent_channels(mu, "normalise_latent");
  return (mu - latent_mean(mu.options())) / latent_std(mu.options());
}
at::Tensor denormalise_latent(const at::Tensor& z_n) {
  check_latent_channels(z_n, "denormalise_latent");
  return z_n * latent_std(z_n.options()) + latent_mean(z_n.options());
}

int64_t video_frames(int64_t latent_frames) {
  FLAT_CHECK(latent_frames >= 1, "video_frames: need at least 1 latent frame, got " + std::to_string(latent_frames));
  return 1 + 4 * (latent_frames - 1);
}
int64_t latent_frames(int64_t video_frames, const std::string& what) {
  FLAT_CHECK(video_frames >= 1 && (video_frames - 1) % 4 == 0,
             what + ": the Wan VAE needs 1+4k frames (1, 5, 9, ..., 49, ..., 81), got " +
                 std::to_string(video_frames));
  return 1 + (video_frames - 1) / 4;
}

int64_t vae_dim_of_file(const std::string& path, const WanVAEConfig& like) {
  const std::string file = resolve_weights_file(path);
  auto mapped = safetensors::MappedFile::open(file);
  const auto& header = mapped->header();
  for (const char* name : {"encoder.conv1.weight", "encoder.conv_in.weight"})
    if (const auto* e = header.find(name); e && e->shape.size() == 5) return e->shape[0];
  for (const char* name : {"decoder.conv1.weight", "decoder.conv_in.weight"})
    if (const auto* e = header.find(name); e && e->shape.size() == 5 && !like.dim_mult.empty())
      return e->shape[0] / like.dim_mult.back();
  fail(file + ": not a Wan 2.1 VAE file (no encoder.conv1.weight or decoder.conv1.weight, in either naming)");
}

WanVAEImpl::WanVAEImpl(const WanVAEConfig& config, const KernelChoices& kernels) : config_(config) {
  config_.check();
  validate_kernels(kernels, "WanVAE");
  const Int3 one{1, 1, 1}, none{0, 0, 0};
  encoder = register_module("encoder", Encoder3d(config_, kernels));
  conv1 = register_module("conv1", CausalConv3d(2 * config_.z_dim, 2 * config_.z_dim, one, one, none,
                                                kernels.conv_backend));
  conv2 = register_module("conv2", CausalConv3d(config_.z_dim, config_.z_dim, one, one, none, kernels.conv_backend));
  decoder = register_module("decoder", Decoder3d(config_, /*scene_variant=*/false, kernels));
}

at::Tensor WanVAEImpl::encode_moments(const at::Tensor& video, bool streaming) {
  check_shape(video, {-1, 3, -1, -1, -1}, "WanVAE::encode: video", "(B,3,F,H,W)");
  const int64_t T = latent_frames(video.size(2), "WanVAE::encode: video " + shape_str(video));
  FLAT_CHECK(video.size(3) % 8 == 0 && video.size(4) % 8 == 0,
             "WanVAE::encode: height and width must be multiples of 8, got " + shape_str(video));
  at::Tensor h;
  if (streaming) {
    StreamCache cache;
    std::vector<at::Tensor> chunks;
    for (int64_t i = 0; i < T; ++i) {
      cache.begin_chunk();
      const int64_t start = i == 0 ? 0 : 1 + 4 * (i - 1);
      chunks.push_back(encoder->forward(video.narrow(2, start, i == 0 ? 1 : 4), &cache));
    }
    h = at::cat(chunks, 2);
  } else {
    h = encoder->forward(video);
  }
  return conv1->forward(h);
}

void WanVAEImpl::fold_latent_statistics(const at::Tensor& mean, const at::Tensor& std) {
  const int64_t z = config_.z_dim;
  FLAT_CHECK(z == 16, "fold_latent_statistics: the Wan 2.1 constants have 16 channels, this VAE has " +
                          std::to_string(z));
  FLAT_CHECK(mean.numel() == z && std.numel() == z, "fold_latent_statistics: mean and std need 16 values each, got " +
                                                        shape_str(mean) + " and " + shape_str(std));
  FLAT_CHECK(at::isfinite(mean).all().item<bool>() && (std > 0).all().item<bool>(),
             "fold_latent_statistics: mean must be finite and std positive");
  torch::NoGradGuard no_grad;
  auto& w1 = conv1->weight;  // (2z, 2z, 1,1,1)
  auto& b1 = conv1->bias;
  auto& w2 = conv2->weight;  // (z, z, 1,1,1)
  auto& b2 = conv2->bias;
  const auto opts = w1.options().dtype(at::kDouble);
  // mu' = a * mu + c per channel.
  const auto a = latent_std(opts).view({z}) / std.to(opts).view({z});
  const auto c = latent_mean(opts).view({z}) - mean.to(opts).view({z}) * a;
  auto W1 = w1.to(at::kDouble), B1 = b1.to(at::kDouble);
  W1.narrow(0, 0, z).mul_(a.view({z, 1, 1, 1, 1}));
  B1.narrow(0, 0, z).mul_(a).add_(c);
  B1.narrow(0, z, z).add_(2.0 * a.log());  // log-variance scales with a^2
  // conv2 sees (x' - c) / a where it saw x.
  auto W2 = w2.to(at::kDouble), B2 = b2.to(at::kDouble);
  const auto w2_flat = W2.reshape({z, z});
  B2.sub_(at::matmul(w2_flat, c / a));
  W2.div_(a.view({1, z, 1, 1, 1}));
  w1.copy_(W1);
  b1.copy_(B1);
  w2.copy_(W2);
  b2.copy_(B2);
}

at::Tensor WanVAEImpl::encode(const at::Tensor& video, bool streaming) {
  at::Tensor moments = encode_moments(video, streaming);
  return normalise_latent(moments.narrow(1, 0, config_.z_dim));
}

at::Tensor WanVAEImpl::decode(const at::Tensor& latent, bool streaming, bool clamp) {
  check_shape(latent, {-1, config_.z_dim, -1, -1, -1}, "WanVAE::decode: latent", "(B,16,T',h,w)");
  at::Tensor z = conv2->forward(denormalise_latent(latent));
  at::Tensor out;
  if (streaming) {
    StreamCache cache;
    std::vector<at::Tensor> chunks;
    for (int64_t i = 0; i < z.size(2); ++i) {
      cache.begin_chunk();
      chunks.push_back(decoder->forward(z.narrow(2, i, 1), &cache));
    }
    out = at::cat(chunks, 2);
  } else {
    out = decoder->forward(z);
  }
  return clamp ? out.clamp(-1, 1) : out;
}

}  // namespace flat::model
