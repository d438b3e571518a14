// Embeds FLAT-C++ as an installed library: reads a stage config (the
// installed configs/tiny/stage1.yaml), builds the scene decoder its
// pipeline.model section describes, and decodes random latents with it.
// Exit 0 only when the output has the shape the config implies.
#include <iostream>

#include "flat/core/config.h"
#include "flat/core/error.h"
#include "flat/model/scene_decoder.h"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::cerr << "usage: flat_consumer <stage config .yaml>\n";
    return 2;
  }
  try {
    YAML::Node root = flat::config::load_yaml_file(argv[1]);
    const auto cfg = flat::config::from_yaml<flat::model::SceneDecoderConfig>(
        root["pipeline"]["model"], std::string(argv[1]) + ": pipeline.model");
    flat::model::SceneDecoder decoder(cfg);
    decoder->eval();
    const int64_t T = 3, h = 6, w = 10;  // latent frames and size
    at::NoGradGuard no_grad;
    const at::Tensor latent = at::randn({1, cfg.vae.z_dim, T, h, w});
    const at::Tensor cameras = at::zeros({1, cfg.camera_channels, T, h, w});
    const at::Tensor out = decoder->forward(latent, cameras);
    std::cout << "flat_consumer: vae.dim " << cfg.vae.dim << ", decoder output " << out.sizes() << "\n";
    // T latent frames decode to 1 + 4 (T - 1) frames at 4x the latent size.
    const bool ok = out.dim() == 5 && out.size(1) == decoder->channels().total && out.size(2) == 1 + 4 * (T - 1) &&
                    out.size(3) == 4 * h && out.size(4) == 4 * w && out.isfinite().all().item<bool>();
    if (!ok) {
      std::cerr << "flat_consumer: unexpected decoder output " << out.sizes() << "\n";
      return 1;
    }
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "flat_consumer: " << e.what() << "\n";
    return 1;
  }
}
