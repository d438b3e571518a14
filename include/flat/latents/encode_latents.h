// Dataset-scale latent precomputation (paper, Model Training: "For each video,
// we precompute its latents using the frozen VAE"), the library behind
// flat_latents. A scene holds one latent set per frame size and window length
// (data/scene.h); this encodes the sets asked for into every scene that lacks
// them:
//   - one scene at a time, each committed as soon as it is encoded (its file
//     renamed into place, then scene.json), so a kill loses at most the scene
//     in flight and a rerun does only what is missing;
//   - a scene that already holds the set, made the same way, is left as it is
//     (byte for byte); one made another way (other weights, windows, dtype) is
//     replaced only with `overwrite`, else reported;
//   - a bad scene (unreadable, missing frames, NaN) is reported with its
//     reason and the run goes on; the summary lists it and the run fails at
//     the end (exit 1), after the rest landed;
//   - the scenes can be split over processes or GPUs: shard K of N takes the
//     scenes K, K+N, ... of the sorted list (a scene's sets all go to one shard,
//     so two processes never write one scene.json);
//   - the spread statistic (do the latents carry the scene?) on a bounded,
//     seeded sample of scenes, so memory stays flat in the number of scenes.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "flat/eval/latent_spread.h"

namespace flat::latents {

// One latent set to make, and the scene folders (or folders of scenes) it is for.
struct LatentSetSpec {
  int64_t height = 0, width = 0;  // frame size to encode at (0 = each scene's, floored to 8)
  int64_t window = 17;            // frames per window, 1+4k
  int64_t step = 0;               // frames between window starts (0 = the window: no overlap)
  bool plucker = false;           // also the Plucker camera latents (conditioning ablation)
  std::vector<std::string> roots;
  std::string origin;             // what asked for it ("--size/--window", "configs/stage3.yaml")
  std::string describe() const;   // "176x320_f17 (17-frame windows at 176x320) for configs/stage1.yaml"
};

struct EncoderSpec {
  std::string weights, weights_prefix;  // a Wan 2.1 VAE file (or a flat_train VAE stage's)
  bool random_weights = false;          // pipeline tests only; recorded as such
  int64_t seed = 0, dim = 0;            // for random_weights (dim 0 = 96)
  std::string device = "auto", precision = "fp32", store = "fp32";
  bool full = false;                    // whole window at once instead of streaming chunks
};

struct EncodeOptions {
  std::vector<LatentSetSpec> sets;
  EncoderSpec encoder;
  bool overwrite = false;
  int64_t shard_index = 0, shard_count = 1;
  int64_t spread_sample = 64;  // scenes whose first window enters the spread statistic
  std::string report_file;     // JSON summary ("" = none)
};

// What happened to one (scene, set).
struct SceneOutcome {
  std::string dir, set;
  std::string reason;
};

struct EncodeSummary {
  int64_t scenes = 0;         // scene folders of this shard
  int64_t encoded = 0;        // (scene, set) pairs encoded and committed
  int64_t present = 0;        // already there, made the same way: left as they were
  int64_t too_short = 0;      // scenes shorter than one window of the set
  int64_t longest = 0;        // frames of the longest scene (for the message when all are short)
  int64_t windows = 0;        // windows encoded
  double seconds = 0;
  std::vector<SceneOutcome> failed;
  eval::LatentSpread spread;
  int64_t spread_scenes = 0;
};

// Encodes what is missing; throws only on errors that concern the whole run
// (bad options, no scene at all, the weights, memory). Per-scene failures are
// in the summary (and the report file).
EncodeSummary encode_latent_sets(const EncodeOptions& options);

// The sets that the stage configs (flat_train YAML) need: each scene-decoder
// stage's data size and window, for its training and validation datasets
// (task: vae stages need none). Sets of the same size and window are merged.
// Each config is read as flat_train reads `--config FILE --config OVERLAY...
// --set KEY=VALUE...`: the overlays layered over it in order, then the
// overrides (full key paths, e.g. "data.datasets=[{root: data/mine}]").
std::vector<LatentSetSpec> latent_sets_for_stages(const std::vector<std::string>& config_files,
                                                  const std::vector<std::string>& overlays = {},
                                                  const std::vector<std::string>& overrides = {});

// "K/N" -> shard index and count; throws naming the text otherwise.
void parse_shard(const std::string& text, int64_t& index, int64_t& count);

}  // namespace flat::latents
