// Choosing the frames of one training sample (paper, Model Training and
// Training Details): an input window of F consecutive frames (17 or 49 by
// stage) and V target views "equally split between seen and unseen views":
// floor(V/2) unseen targets are frames of the same video outside the window,
// the rest are seen targets inside it. When the video has too few frames
// outside the window, the missing unseen targets become seen ones.
#pragma once
#include <cstdint>
#include <random>
#include <vector>

#include "flat/data/scene.h"

namespace flat::data {

struct ViewSamplerConfig {
  int64_t input_frames = 17;    // F = 1 + 4k
  int64_t target_views = 17;    // V
  double unseen_fraction = 0.5; // share of targets outside the window
  int64_t frame_stride = 1;     // window frames start, start+s, start+2s, ...
  int64_t unseen_max_gap = 0;   // unseen targets at most this many frames from the window (0 = any)
};

struct ViewSample {
  std::vector<int64_t> input;    // F frame indices, increasing
  std::vector<int64_t> targets;  // V frame indices: seen ones first, then unseen, each increasing
  std::vector<bool> seen;        // V flags
  int64_t latent_window = -1;    // index into scene.latents.windows, or -1
};

// Frames a scene needs for one window.
int64_t window_span(const ViewSamplerConfig& c);

// With `latent_windows`, the window is one of the scene's latent windows of F
// frames (its index is returned); else any window that fits.
ViewSample sample_views(int64_t scene_frames, const ViewSamplerConfig& c, std::mt19937_64& rng,
                        const std::vector<LatentWindow>* latent_windows = nullptr);

}  // namespace flat::data
