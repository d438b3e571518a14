#include "flat/model/scene_decoder.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/model/wan_vae.h"

namespace flat::model {

SceneDecoderImpl::SceneDecoderImpl(const SceneDecoderConfig& config, const primitives::TriangleChannels& layout)
    : config_(config) {
  config_.vae.check();
  if (config_.camera) {
    adapter = register_module("adapter", CameraAdapter(config_.camera_channels, config_.vae.z_dim,
                                                       config_.adapter_zero_kernel));
  }
  conv2 = register_module("conv2", CausalConv3d(config_.vae.z_dim, config_.vae.z_dim, Int3{1, 1, 1}));
  decoder = register_module("decoder", Decoder3d(config_.vae, /*scene_variant=*/true));
  heads = register_module("heads", OutputHeads(decoder->out_features(), layout, config_.heads));
}

at::Tensor SceneDecoderImpl::channels_last_input(const at::Tensor& x) const {
  const bool cl = decoder->conv1->weight.is_contiguous(at::MemoryFormat::ChannelsLast3d) &&
                  !decoder->conv1->weight.is_contiguous();
  return cl ? x.contiguous(at::MemoryFormat::ChannelsLast3d) : x;
}

at::Tensor SceneDecoderImpl::chunk(const at::Tensor& latent, const at::Tensor& camera_latents, StreamCache* cache,
                                   bool with_heads) {
  at::Tensor z = latent;
  if (camera_latents.defined()) z = z + adapter->forward(camera_latents, cache);
  z = channels_last_input(conv2->forward(denormalise_latent(z)));
  at::Tensor f = decoder->forward(z, cache);
  return with_heads ? heads->forward(f, cache) : f;
}

at::Tensor SceneDecoderImpl::run(const at::Tensor& latent, const at::Tensor& camera_latents, bool streaming,
                                 bool with_heads) {
  check_shape(latent, {-1, config_.vae.z_dim, -1, -1, -1}, "SceneDecoder: latent", "(B,16,T',h,w)");
  if (camera_latents.defined()) {
    FLAT_CHECK(adapter, "SceneDecoder: camera latents given but the model was built with camera = false");
    FLAT_CHECK(camera_latents.dim() == 5 && camera_latents.size(0) == latent.size(0) &&
                   camera_latents.size(1) == config_.camera_channels && camera_latents.size(2) == latent.size(2) &&
                   camera_latents.size(3) == latent.size(3) && camera_latents.size(4) == latent.size(4),
               "SceneDecoder: camera latents " + shape_str(camera_latents) + " do not match the latent " +
                   shape_str(latent) + " (expected (B," + std::to_string(config_.camera_channels) + ",T',h,w))");
  }
  if (!streaming) return chunk(latent, camera_latents, nullptr, with_heads);
  StreamCache cache;
  std::vector<at::Tensor> outs;
  for (int64_t i = 0; i < latent.size(2); ++i) {
    cache.begin_chunk();
    at::Tensor cam = camera_latents.defined() ? camera_latents.narrow(2, i, 1) : at::Tensor();
    outs.push_back(chunk(latent.narrow(2, i, 1), cam, &cache, with_heads));
  }
  return at::cat(outs, 2);
}

at::Tensor SceneDecoderImpl::forward(const at::Tensor& latent, const at::Tensor& camera_latents, bool streaming) {
  return run(latent, camera_latents, streaming, /*with_heads=*/true);
}

at::Tensor SceneDecoderImpl::features(const at::Tensor& latent, const at::Tensor& camera_latents, bool streaming) {
  return run(latent, camera_latents, streaming, /*with_heads=*/false);
}

LoadReport SceneDecoderImpl::load_pretrained_vae(const std::string& path) {
  LoadSpec spec;
  // The RGB head (decoder.head.*) does not exist in the scene variant; the
  // encoder and conv1 belong to the encoding side.
  spec.take = {"conv2.", "decoder.conv1.", "decoder.middle.", "decoder.upsamples."};
  spec.keep_initialised = {"adapter.", "heads."};
  return load_weights(*this, path, spec);
}

}  // namespace flat::model
