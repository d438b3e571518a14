// loss.random_background: a training render's uncovered share (1 - alpha)
// takes a colour drawn per view instead of the configured background
// (pipeline.raster.background); validation and evaluation keep the configured
// one. Over a fixed black background a decoder can paint a dark surface with
// low-opacity triangles, and stage 4's pruning below 40% opacity then cuts
// holes where the dark surfaces were (docs/training.md, "The four stages").
// Over a colour that changes every step, only opaque triangles make a dark
// surface. The compositing ends with T_final * background, T_final = 1 - alpha,
// so replacing the background is
//   rgb' = rgb + (1 - alpha) * (colour - configured).
#pragma once
#include <cstdint>
#include <vector>

#include "flat/pipeline/scene_pipeline.h"

namespace flat::train {

// Replaces views.rgb's background by one colour per view, uniform in [0,1]^3,
// drawn from a generator seeded with `seed` (the same seed, the same colours:
// a resumed run draws what the uninterrupted one drew). Differentiable in
// rgb and alpha. Returns the colours, (V,3).
at::Tensor use_random_background(pipeline::RenderedViews& views, const std::vector<double>& configured,
                                 uint64_t seed);

}  // namespace flat::train
