// Small random Gaussian scenes for the Gaussian rasterizer tests (CPU and CUDA).
#pragma once
#include <torch/torch.h>

#include "render/render_scenes.h"  // test_cameras()

namespace flat::test {

struct Gaussians {
  torch::Tensor means, scales, rotations, colors, opacities;  // (N,3), (N,3), (N,4), (N,3), (N)
};

// N Gaussians in front of the test cameras: means in x in [-1,1], y in
// [-0.7,0.7], z in [2,4]; scales (standard deviations) in [lo, hi] per axis;
// random rotations given as quaternions of norm 0.5 to 2 (not unit).
inline Gaussians random_gaussians(int64_t n, torch::Dtype dtype, uint64_t seed, double lo = 0.08, double hi = 0.3) {
  auto gen = at::make_generator<at::CPUGeneratorImpl>(seed);
  auto opts = torch::TensorOptions().dtype(torch::kDouble);
  auto u = [&](std::vector<int64_t> shape, double a, double b) { return at::rand(shape, gen, opts) * (b - a) + a; };
  Gaussians g;
  g.means = torch::stack({u({n}, -1, 1), u({n}, -0.7, 0.7), u({n}, 2, 4)}, -1).to(dtype);
  g.scales = u({n, 3}, lo, hi).to(dtype);
  auto q = at::randn({n, 4}, gen, opts);
  g.rotations = (q / q.norm(2, 1, true) * u({n, 1}, 0.5, 2.0)).to(dtype);
  g.colors = u({n, 3}, 0, 1).to(dtype);
  g.opacities = u({n}, 0.3, 0.9).to(dtype);
  return g;
}

}  // namespace flat::test
