// The FLAT scene decoder (paper: Feedforward Scene Decoder; appendix, Scene
// Decoder Architecture): camera adapter -> Wan 2.1 decoder with the last x2
// spatial upsample removed -> triangle heads.
//
//   latent z_n (B,16,T',h,w), normalised      camera latents (B,32,T',h,w)
//   z_n + adapter(camera latents)             (zero at initialisation)
//   -> denormalise -> conv2 (1x1x1) -> Decoder3d(scene variant): 96 ch at (T, 4h, 4w)
//   -> heads: raw parameters (B, channels.total, T, 4h, 4w), T = 1 + 4(T'-1)
//
// The adapter adds to the normalised latent, the space the video model works
// in. Parameter names: "adapter.*", "conv2.*", "decoder.*" (original Wan names,
// so a Wan VAE file initialises conv2 and the decoder), "heads.*".
#pragma once
#include <cstdint>
#include <functional>
#include <string>

#include <ATen/ATen.h>
#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "flat/core/config.h"
#include "flat/model/camera_adapter.h"
#include "flat/model/decoder3d.h"
#include "flat/model/kernel_choices.h"
#include "flat/model/output_heads.h"
#include "flat/model/wan_vae_config.h"
#include "flat/model/weights.h"

namespace flat::model {

struct SceneDecoderConfig {
  WanVAEConfig vae;                  // the decoder's architecture (dim 96 = pretrained)
  std::string heads = "independent";  // "independent" | "monolithic"
  bool camera = true;                // build the camera adapter
  int64_t camera_channels = 32;      // [E_ref; E_dir]
  int64_t adapter_zero_kernel = 3;   // the zero conv's kernel (3: 3x3x3, 1: 1x1x1)
  // Ablations of the paper's Camera Conditioning (Table "Ablation studies"):
  // the rays the camera latents encode ("rppc", the paper, or "plucker"; the
  // data must hold them: flat_latents --camera-rays), and whether the fusion
  // conv starts at zero (false: PyTorch's default init, so the pretrained
  // decoder sees a random camera term from the first step).
  std::string camera_rays = "rppc";
  bool adapter_zero_init = true;
  // Streaming: latent frames the low-resolution trunk (adapter, conv1, middle,
  // up to the first temporal upsample) takes per step. Its activations are
  // small (~14 MB a latent frame at 54x96, bf16), and one frame at a time
  // leaves the GPU idle there; the high-resolution rest always streams one
  // latent frame at a time. Any value gives the same output.
  int64_t stream_trunk_frames = 16;
  // Training: recompute the decoder's blocks in the backward instead of keeping
  // their activations (paper, stage 4: gradient checkpointing). Same gradients.
  bool activation_checkpointing = false;
  // Which kernels run the norms, convs and upsamples (speed only, same
  // outputs); the modules keep them from construction (kernel_choices.h).
  KernelChoices kernels;

  template <class V>
  void visit(V& v) {
    v.section("vae", vae);
    v.field("heads", heads, config::one_of({"independent", "monolithic"}), "one head per parameter group, or one");
    v.field("camera", camera, "camera conditioning through the zero-initialised adapter");
    v.field("camera_channels", camera_channels, config::positive(), "channels of the camera latents");
    v.field("adapter_zero_kernel", adapter_zero_kernel, config::range(1, 3), "kernel of the zero conv: 1 or 3");
    v.field("camera_rays", camera_rays, config::one_of({"rppc", "plucker"}),
            "rays of the camera latents: rppc (paper) | plucker (ablation; needs flat_latents --camera-rays)");
    v.field("adapter_zero_init", adapter_zero_init, "start the fusion conv at zero (paper); false: the ablation");
    v.field("stream_trunk_frames", stream_trunk_frames, config::positive(),
            "streaming: latent frames per step of the low-resolution trunk");
    v.field("activation_checkpointing", activation_checkpointing,
            "training: recompute decoder blocks in the backward (less memory, one more forward)");
    v.section("kernels", kernels);
  }
};

class SceneDecoderImpl : public torch::nn::Module {
 public:
  // layout: the heads' output channels (the triangle parameterisation and
  // colour model: primitives::TriangleParamConfig::channels()); the default is
  // the paper's ray-centred RGB layout, 12 channels.
  explicit SceneDecoderImpl(const SceneDecoderConfig& config = {},
                            const primitives::HeadChannels& layout = primitives::triangle_channels("ray_centred"));

  // latent (B,16,T',h,w) normalised; camera_latents (B,32,T',h,w) or undefined
  // (no camera term). Returns raw head outputs (B, channels().total, T, 4h, 4w).
  // streaming: one latent frame at a time with per-layer caches (bounded memory).
  at::Tensor forward(const at::Tensor& latent, const at::Tensor& camera_latents = {}, bool streaming = false);
  // Streaming decode that hands each latent frame's head outputs to `sink` as
  // soon as they exist (B, C, t, 4h, 4w; t = 1 for latent frame 0, 4 for the
  // others, in order) instead of concatenating them: the caller turns them into
  // triangles and moves them off the GPU, so decoding memory does not grow
  // with the number of latent frames.
  void forward_chunks(const at::Tensor& latent, const at::Tensor& camera_latents,
                      const std::function<void(const at::Tensor&)>& sink);
  // The 96-channel decoder features before the heads (same arguments).
  at::Tensor features(const at::Tensor& latent, const at::Tensor& camera_latents = {}, bool streaming = false);

  // x re-laid out as ChannelsLast3d when the weights are (to_channels_last_3d).
  at::Tensor channels_last_input(const at::Tensor& x) const;

  const primitives::HeadChannels& channels() const { return heads->channels(); }
  const SceneDecoderConfig& config() const { return config_; }

  // Initialise conv2 and the decoder from a Wan 2.1 VAE file (either naming);
  // the encoder, conv1 and the RGB head in the file are not used, the adapter
  // and heads keep their initialisation. Throws on any other mismatch.
  LoadReport load_pretrained_vae(const std::string& path);

  CameraAdapter adapter{nullptr};
  CausalConv3d conv2{nullptr};
  Decoder3d decoder{nullptr};
  OutputHeads heads{nullptr};

 private:
  SceneDecoderConfig config_;
  // sink: streaming only; receives each latent frame's output instead of the concatenation (then undefined is returned).
  at::Tensor run(const at::Tensor& latent, const at::Tensor& camera_latents, bool streaming, bool with_heads,
                 const std::function<void(const at::Tensor&)>* sink = nullptr);
  // adapter, conv2 and the decoder's first `split` stages / the rest and the heads.
  at::Tensor trunk(const at::Tensor& latent, const at::Tensor& camera_latents, StreamCache* cache, size_t split);
  at::Tensor tail(at::Tensor h, StreamCache* cache, size_t split, bool with_heads);
};
TORCH_MODULE(SceneDecoder);

}  // namespace flat::model
