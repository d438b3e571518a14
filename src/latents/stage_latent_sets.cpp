// Which latent sets a list of flat_train stage configs needs, so that one
// flat_latents call prepares the datasets of all four stages of the paper
// (17 and 49 frames at 176x320, 49 at 360x640 and at 432x768).
#include <algorithm>
#include <map>
#include <tuple>

#include "flat/core/config.h"
#include "flat/core/error.h"
#include "flat/data/scene.h"
#include "flat/latents/encode_latents.h"
#include "flat/train/train_config.h"

namespace flat::latents {

std::vector<LatentSetSpec> latent_sets_for_stages(const std::vector<std::string>& config_files,
                                                  const std::vector<std::string>& overlays,
                                                  const std::vector<std::string>& overrides) {
  std::map<std::tuple<int64_t, int64_t, int64_t>, LatentSetSpec> sets;
  for (const auto& file : config_files) {
    std::vector<std::string> layers = {file};
    layers.insert(layers.end(), overlays.begin(), overlays.end());
    const auto cfg = config::load_layered<train::TrainConfig>("", "<defaults>", layers, overrides);
    if (cfg.task != "scene" || !cfg.data.latents) continue;  // a VAE stage encodes its frames itself
    auto& s = sets[{cfg.data.height, cfg.data.width, cfg.data.input_frames}];
    s.height = cfg.data.height;
    s.width = cfg.data.width;
    s.window = cfg.data.input_frames;
    s.plucker = s.plucker || cfg.pipeline.model.camera_rays == "plucker";
    s.origin += (s.origin.empty() ? "" : ", ") + file;
    for (const auto* list : {&cfg.data.datasets, &cfg.validation.datasets})
      for (const auto& d : *list)
        if (std::find(s.roots.begin(), s.roots.end(), d.root) == s.roots.end()) s.roots.push_back(d.root);
  }
  std::vector<LatentSetSpec> out;
  for (auto& [key, s] : sets) out.push_back(std::move(s));
  if (out.empty()) fail("flat_latents --configs: none of the configs trains a scene decoder on latents");
  return out;
}

}  // namespace flat::latents
