// Camera trajectories for the synthetic scenes (internal).
#pragma once
#include <array>
#include <string>
#include <vector>

#include "data/synthetic/shapes.h"

namespace flat::data::synth {

struct Path {
  std::vector<std::array<double, 16>> c2w;  // row-major 4x4, OpenCV camera axes
  double hfov = 1.0;                        // horizontal field of view, radians
  std::string motion;                       // pan | zoom | orbit
};

Path make_path(const Layout& layout, bool room, const std::string& motion, int64_t frames, Random& rng);

}  // namespace flat::data::synth
