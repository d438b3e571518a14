// The sRGB transfer function (IEC 61966-2-1). Our colours are display values
// (the space of the images they were fitted to); glTF vertex colours are
// linear, so the GLB writer converts on the way out and the reader back.
#pragma once
#include <cmath>

namespace flat::exporter {

inline float srgb_to_linear(float s) {
  const double x = s;
  return float(x <= 0.04045 ? x / 12.92 : std::pow((x + 0.055) / 1.055, 2.4));
}

inline float linear_to_srgb(float l) {
  const double x = l;
  return float(x <= 0.0031308 ? x * 12.92 : 1.055 * std::pow(x, 1.0 / 2.4) - 0.055);
}

}  // namespace flat::exporter
