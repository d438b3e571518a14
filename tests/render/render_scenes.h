// Small random scenes for the rasterizer tests (CPU and CUDA).
#pragma once
#include <cmath>

#include <torch/torch.h>

#include "flat/camera/cameras.h"

namespace flat::test {

struct Soup {
  torch::Tensor vertices, colors, opacities, sigmas;  // (N,3,3), (N,3), (N), (N)
};

// N triangles in front of cameras near the origin looking down +z: centres in
// x in [-1,1], y in [-0.7,0.7], z in [2,4], vertex offsets up to `size`.
inline Soup random_soup(int64_t n, torch::Dtype dtype, uint64_t seed, double size = 0.5) {
  auto gen = at::make_generator<at::CPUGeneratorImpl>(seed);
  auto opts = torch::TensorOptions().dtype(torch::kDouble);
  auto u = [&](std::vector<int64_t> shape, double lo, double hi) {
    return at::rand(shape, gen, opts) * (hi - lo) + lo;
  };
  auto centre = torch::stack({u({n}, -1, 1), u({n}, -0.7, 0.7), u({n}, 2, 4)}, -1);
  auto verts = centre.unsqueeze(1) + u({n, 3, 3}, -size, size);
  Soup s;
  s.vertices = verts.to(dtype);
  s.colors = u({n, 3}, 0, 1).to(dtype);
  s.opacities = u({n}, 0.3, 0.9).to(dtype);
  s.sigmas = u({n}, 0.5, 2.0).to(dtype);
  return s;
}

// V cameras at small offsets from the origin, slightly rotated, all looking
// towards +z; normalised intrinsics for a 4:3 image. step scales the offset
// and turn from one view to the next.
inline camera::Cameras test_cameras(int64_t views, double step = 1.0) {
  camera::Cameras c;
  c.intrinsics = torch::tensor({0.9, 1.2, 0.5, 0.5}, torch::kFloat).repeat({views, 1});
  c.c2w = torch::eye(4, torch::kFloat).repeat({views, 1, 1});
  for (int64_t v = 0; v < views; ++v) {
    const double s = step * double(v);
    const double a = 0.08 * s, b = -0.05 * s;
    auto R = torch::tensor({{std::cos(a), 0.0, std::sin(a)}, {0.0, 1.0, 0.0}, {-std::sin(a), 0.0, std::cos(a)}});
    auto Rx = torch::tensor({{1.0, 0.0, 0.0}, {0.0, std::cos(b), -std::sin(b)}, {0.0, std::sin(b), std::cos(b)}});
    c.c2w[v].narrow(0, 0, 3).narrow(1, 0, 3).copy_(torch::matmul(R, Rx));
    c.c2w[v][0][3] = 0.1 * s;
    c.c2w[v][1][3] = -0.05 * s;
  }
  return c;
}

}  // namespace flat::test
