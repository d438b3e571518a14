// Small random surfel scenes for the surfel rasterizer tests (CPU and CUDA).
#pragma once
#include <cmath>

#include <torch/torch.h>

#include "render/render_scenes.h"  // test_cameras()

namespace flat::test {

struct Surfels {
  torch::Tensor means, scales, rotations, colors, opacities;  // (N,3), (N,2), (N,4), (N,3), (N)
};

// N surfels in front of the test cameras (centres x in [-1,1], y in
// [-0.7,0.7], z in [2,4]); scales log-uniform in [scale_lo, scale_hi] (the
// small ones fall under the low-pass filter); normals tilted at most 1 rad
// from the optical axis (never edge-on), half of them facing away from the
// cameras; quaternions not unit (norms in [0.5, 2]).
inline Surfels random_surfels(int64_t n, torch::Dtype dtype, uint64_t seed, double scale_lo = 0.03,
                              double scale_hi = 0.4) {
  auto gen = at::make_generator<at::CPUGeneratorImpl>(seed);
  auto opts = torch::TensorOptions().dtype(torch::kDouble);
  auto u = [&](std::vector<int64_t> shape, double lo, double hi) {
    return at::rand(shape, gen, opts) * (hi - lo) + lo;
  };
  Surfels s;
  s.means = torch::stack({u({n}, -1, 1), u({n}, -0.7, 0.7), u({n}, 2, 4)}, -1).to(dtype);
  s.scales = torch::exp(u({n, 2}, std::log(scale_lo), std::log(scale_hi))).to(dtype);
  // q = tilt * spin: spin a about z, then tilt b about an axis in the xy plane.
  auto a = u({n}, 0, 2 * M_PI), c = u({n}, 0, 2 * M_PI);
  auto b = u({n}, 0, 1.0) + M_PI * (u({n}, 0, 1) > 0.5).to(torch::kDouble);
  auto zw = torch::cos(a / 2), zz = torch::sin(a / 2);
  auto tw = torch::cos(b / 2), tx = torch::sin(b / 2) * torch::cos(c), ty = torch::sin(b / 2) * torch::sin(c);
  // (tw, tx, ty, 0) (zw, 0, 0, zz) = (tw zw, tx zw + ty zz, ty zw - tx zz, tw zz)
  auto q = torch::stack({tw * zw, tx * zw + ty * zz, ty * zw - tx * zz, tw * zz}, -1);
  s.rotations = (q * u({n, 1}, 0.5, 2.0)).to(dtype);
  s.colors = u({n, 3}, 0, 1).to(dtype);
  s.opacities = u({n}, 0.3, 0.95).to(dtype);
  return s;
}

}  // namespace flat::test
