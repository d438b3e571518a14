// A view's depth re-solved from the soup's normals (issue #44): texture in
// the depth no longer tilts the grid's faces, and a real depth step stays a step.
#include <torch/torch.h>

#include "flat/mesh/depth_grid_mesh.h"
#include "flat/mesh/normal_guided_depth.h"
#include "test_support.h"

using namespace flat;

namespace {

const auto kIntrinsics = torch::tensor({0.9f, 1.2f, 0.5f, 0.5f});
constexpr int64_t H = 13, W = 21;

// z of the plane n.X = n.(0,0,3) through every pixel centre's ray (camera at the origin).
at::Tensor plane_depth(const at::Tensor& n) {
  const double fx = 0.9 * W, fy = 1.2 * H, cx = 0.5 * W, cy = 0.5 * H;
  auto z = torch::zeros({H, W});
  const double c = 3.0 * n[2].item<double>();
  for (int64_t v = 0; v < H; ++v)
    for (int64_t u = 0; u < W; ++u) {
      const double x = (u + 0.5 - cx) / fx, y = (v + 0.5 - cy) / fy;
      z[v][u] = float(c / (n[0].item<double>() * x + n[1].item<double>() * y + n[2].item<double>()));
    }
  return z;
}

// Unit face normals of the grid mesh of a depth map (camera = world).
at::Tensor grid_face_normals(const at::Tensor& depth) {
  const auto m = mesh::depth_grid_mesh(depth, torch::full({3, H, W}, 0.5f), torch::ones({H, W}, torch::kBool),
                                       kIntrinsics, torch::eye(4), {});
  const auto c = m.vertices.index_select(0, m.faces.reshape({-1})).reshape({-1, 3, 3});
  const auto n = at::cross(c.select(1, 1) - c.select(1, 0), c.select(1, 2) - c.select(1, 0), -1);
  return n / n.norm(2, -1, true);
}

}  // namespace

TEST_CASE("normal-guided depth: a textured tilted plane comes back flat, at its depth", "[mesh]") {
  auto n = torch::tensor({0.3f, -0.2f, -1.0f});
  n = n / n.norm();
  const auto truth = plane_depth(n);
  // A checkerboard of 2x2 blocks in the depth, +-4%: the texture leaking into a soup's rendered depth.
  const auto u = torch::arange(W).div(2, "floor").unsqueeze(0), v = torch::arange(H).div(2, "floor").unsqueeze(1);
  const auto checker = ((u + v).remainder(2) * 2 - 1).to(torch::kFloat);
  const auto noisy = truth * (1 + 0.04f * checker);
  const auto normals = n.reshape({3, 1, 1}).expand({3, H, W}).contiguous();
  const auto solved = mesh::normal_guided_depth(noisy, normals, torch::ones({H, W}, torch::kBool), kIntrinsics);
  INFO("relative depth error: rendered " << ((noisy - truth) / truth).abs().max().item<double>() << ", solved "
                                         << ((solved - truth) / truth).abs().max().item<double>());
  CHECK(((solved - truth) / truth).abs().max().item<double>() < 0.01);
  // Every face of the solved grid lies in the plane; the rendered depth's grid tilts its faces with the texture.
  const double solved_cos = (grid_face_normals(solved) * n).sum(-1).min().item<double>();
  const double noisy_cos = (grid_face_normals(noisy) * n).sum(-1).min().item<double>();
  INFO("worst face normal cosine: rendered depth " << noisy_cos << ", solved " << solved_cos);
  CHECK(solved_cos > 0.999);
  CHECK(noisy_cos < 0.95);
}

TEST_CASE("normal-guided depth: a depth step stays a step, invalid samples keep their depth", "[mesh]") {
  // A box's front at 2 m before a wall at 3 m, both facing the camera: the normals predict no step.
  auto depth = torch::full({H, W}, 3.0f);
  depth.narrow(1, 0, 10).fill_(2.0f);
  auto valid = torch::ones({H, W}, torch::kBool);
  valid[6][15] = false;
  depth[6][15] = 7.0f;
  auto normals = torch::zeros({3, H, W});
  normals[2].fill_(-1.0f);
  const auto solved = mesh::normal_guided_depth(depth, normals, valid, kIntrinsics);
  // A front-facing plane has constant z: the solution is the input, the step kept (log 3/2 > max_step 0.3).
  CHECK((solved - depth).abs().max().item<double>() < 1e-3);
  CHECK(solved[6][15].item<float>() == 7.0f);
  // With the cut switched off in effect (max_step beyond the step), the step is smoothed into a ramp:
  // what the cut prevents.
  mesh::NormalGuidedDepthOptions loose;
  loose.max_step = 1.0;
  const auto ramp = mesh::normal_guided_depth(depth, normals, valid, kIntrinsics, loose);
  CHECK((ramp - depth).abs().max().item<double>() > 0.3);
}

TEST_CASE("normal-guided depth names the wrong shape", "[mesh]") {
  const auto depth = torch::full({H, W}, 3.0f);
  CHECK_THROWS_WITH(mesh::normal_guided_depth(depth, torch::zeros({3, H, W + 1}), torch::ones({H, W}, torch::kBool),
                                              kIntrinsics),
                    FLAT_CONTAINS("normals must be (3,13,21)"));
}
