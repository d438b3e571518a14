#include "flat/model/scene_decoder.h"

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/model/wan_vae.h"

namespace flat::model {

SceneDecoderImpl::SceneDecoderImpl(const SceneDecoderConfig& config, const primitives::HeadChannels& layout)
    : config_(config) {
  config_.vae.check();
  const KernelChoices& kernels = config_.kernels;
  validate_kernels(kernels, "SceneDecoderConfig");
  if (config_.camera) {
    adapter = register_module("adapter", CameraAdapter(config_.camera_channels, config_.vae.z_dim,
                                                       config_.adapter_zero_kernel, config_.adapter_zero_init, kernels));
  }
  conv2 = register_module("conv2", CausalConv3d(config_.vae.z_dim, config_.vae.z_dim, Int3{1, 1, 1}, Int3{1, 1, 1},
                                                Int3{0, 0, 0}, kernels.conv_backend));
  decoder = register_module("decoder", Decoder3d(config_.vae, /*scene_variant=*/true, kernels));
  decoder->set_activation_checkpointing(config_.activation_checkpointing);
  heads = register_module("heads", OutputHeads(decoder->out_features(), layout, config_.heads, kernels));
}

at::Tensor SceneDecoderImpl::channels_last_input(const at::Tensor& x) const {
  const bool cl = decoder->conv1->weight.is_contiguous(at::MemoryFormat::ChannelsLast3d) &&
                  !decoder->conv1->weight.is_contiguous();
  return cl ? x.contiguous(at::MemoryFormat::ChannelsLast3d) : x;
}

at::Tensor SceneDecoderImpl::trunk(const at::Tensor& latent, const at::Tensor& camera_latents, StreamCache* cache,
                                   size_t split) {
  at::Tensor z = latent;
  if (camera_latents.defined()) z = z + adapter->forward(camera_latents, cache);
  z = channels_last_input(conv2->forward(denormalise_latent(z)));
  return decoder->forward_trunk(z, cache, split);
}

at::Tensor SceneDecoderImpl::tail(at::Tensor h, StreamCache* cache, size_t split, bool with_heads) {
  at::Tensor f = decoder->forward_tail(std::move(h), cache, split);
  return with_heads ? heads->forward(f, cache) : f;
}

at::Tensor SceneDecoderImpl::run(const at::Tensor& latent, const at::Tensor& camera_latents, bool streaming,
                                 bool with_heads, const std::function<void(const at::Tensor&)>* sink) {
  check_shape(latent, {-1, config_.vae.z_dim, -1, -1, -1}, "SceneDecoder: latent", "(B,16,T',h,w)");
  if (camera_latents.defined()) {
    FLAT_CHECK(adapter, "SceneDecoder: camera latents given but the model was built with camera = false");
    FLAT_CHECK(camera_latents.dim() == 5 && camera_latents.size(0) == latent.size(0) &&
                   camera_latents.size(1) == config_.camera_channels && camera_latents.size(2) == latent.size(2) &&
                   camera_latents.size(3) == latent.size(3) && camera_latents.size(4) == latent.size(4),
               "SceneDecoder: camera latents " + shape_str(camera_latents) + " do not match the latent " +
                   shape_str(latent) + " (expected (B," + std::to_string(config_.camera_channels) + ",T',h,w))");
  }
  const size_t split = decoder->trunk_stages();
  if (!streaming) return tail(trunk(latent, camera_latents, nullptr, split), nullptr, split, with_heads);
  // The trunk takes stream_trunk_frames latent frames per step; its output is
  // cut per latent frame (after its temporal x2: 1 frame for latent frame 0,
  // 2 for every other) and the tail streams those one at a time.
  FLAT_CHECK(config_.stream_trunk_frames > 0, "SceneDecoder: stream_trunk_frames must be positive");
  const int64_t T = latent.size(2), step = config_.stream_trunk_frames;
  StreamCache trunk_cache, tail_cache;
  std::vector<at::Tensor> outs;
  for (int64_t i = 0; i < T; i += step) {
    const int64_t n = std::min(step, T - i);
    trunk_cache.begin_chunk();
    at::Tensor cam = camera_latents.defined() ? camera_latents.narrow(2, i, n) : at::Tensor();
    const at::Tensor h = trunk(latent.narrow(2, i, n), cam, &trunk_cache, split);
    int64_t frame = 0;
    for (int64_t j = i; j < i + n; ++j) {
      const int64_t frames = Decoder3dImpl::trunk_frames(j, split);
      tail_cache.begin_chunk();
      at::Tensor out = tail(h.narrow(2, frame, frames), &tail_cache, split, with_heads);
      if (sink) {
        (*sink)(out);
      } else {
        outs.push_back(out);
      }
      frame += frames;
    }
    FLAT_CHECK(frame == h.size(2), "SceneDecoder: the streaming trunk gave " + std::to_string(h.size(2)) +
                                       " frames for " + std::to_string(n) + " latent frames");
  }
  return sink ? at::Tensor() : at::cat(outs, 2);
}

void SceneDecoderImpl::forward_chunks(const at::Tensor& latent, const at::Tensor& camera_latents,
                                      const std::function<void(const at::Tensor&)>& sink) {
  run(latent, camera_latents, /*streaming=*/true, /*with_heads=*/true, &sink);
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
