// The mean of per-view (or per-scene) scores, NaN when there are none: a
// score never measured reads as missing, not as 0.
#pragma once
#include <cmath>
#include <vector>

namespace flat::eval {

inline double mean_of(const std::vector<double>& x) {
  double s = 0;
  for (double v : x) s += v;
  return x.empty() ? NAN : s / double(x.size());
}

}  // namespace flat::eval
