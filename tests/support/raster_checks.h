// Scaffolding shared by the three rasterizers' tests (tests/render,
// tests/gaussians, tests/surfels): a random linear functional of the outputs
// (the loss whose gradients are checked), the finite-difference check of the
// CPU references, and the measures of the CUDA-vs-CPU comparisons. The
// rasterizer-specific parts (scenes, tolerances) stay with each test.
#pragma once
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <torch/torch.h>

#include "flat/render/rasterize.h"
#include "test_support.h"

namespace flat::test {

// Which differentiable outputs a Probe weighs besides rgb, alpha and depth.
// only_distortion: the distortion map alone (its gradient is otherwise a
// small part of the total, and colours get none).
struct ProbeOutputs {
  bool normal = false;
  bool distortion = false;
  bool only_distortion = false;
};

// A random linear functional of the differentiable outputs: sum of each
// output times a random weight of its shape. Weights drawn from `gen` (none:
// the global generator) in the order rgb, alpha, depth, normal, distortion;
// depth's scaled by 0.3, the distortion's (small values) by 100.
struct Probe {
  torch::Tensor rgb, alpha, depth, normal, distortion;  // undefined when not weighed

  Probe(int64_t V, int64_t H, int64_t W, const ProbeOutputs& which, std::optional<at::Generator> gen,
        torch::Dtype dtype) {
    const auto o = torch::TensorOptions().dtype(dtype);
    const double on = which.only_distortion ? 0.0 : 1.0;
    rgb = at::randn({V, 3, H, W}, gen, o) * on;
    alpha = at::randn({V, 1, H, W}, gen, o) * on;
    depth = at::randn({V, 1, H, W}, gen, o) * (0.3 * on);
    if (which.normal) normal = at::randn({V, 3, H, W}, gen, o) * on;
    if (which.distortion) distortion = at::randn({V, 1, H, W}, gen, o) * 100.0;
  }

  // The weights follow the outputs to their device.
  torch::Tensor operator()(const render::RenderOutput& r) const {
    const auto dev = r.rgb.device();
    torch::Tensor loss = (r.rgb * rgb.to(dev)).sum() + (r.alpha * alpha.to(dev)).sum() + (r.depth * depth.to(dev)).sum();
    if (normal.defined()) loss = loss + (r.normal * normal.to(dev)).sum();
    if (distortion.defined()) loss = loss + (r.distortion * distortion.to(dev)).sum();
    return loss;
  }
};

// A rasterizer called on a full list of its inputs (the scene's tensors).
using RenderFn = std::function<render::RenderOutput(const std::vector<torch::Tensor>&)>;

// The analytic gradients `grads` of probe(render(inputs)) against central
// finite differences (step 1e-6, double) of every element of every input but
// inputs[skip] (-1: none): each gradient non-zero, within 1e-5 relative L2
// and 1e-4 of (1 + the largest) element-wise. `inputs`: the values the
// gradients were taken at.
inline void check_against_fd(const std::vector<torch::Tensor>& inputs, const std::vector<torch::Tensor>& grads,
                             const std::vector<std::string>& names, const RenderFn& render, const Probe& probe,
                             int skip = -1) {
  const double h = 1e-6;
  torch::NoGradGuard ng;
  for (size_t which = 0; which < inputs.size(); ++which) {
    if ((int)which == skip) continue;
    auto base = inputs[which].detach().clone();
    auto fd = torch::zeros_like(base);
    auto flat_fd = fd.view({-1});
    for (int64_t i = 0; i < base.numel(); ++i) {
      auto eval = [&](double delta) {
        auto x = base.clone();
        x.view({-1})[i] += delta;
        std::vector<torch::Tensor> in;
        for (const auto& t : inputs) in.push_back(t.detach());
        in[which] = x;
        return probe(render(in)).item<double>();
      };
      flat_fd[i] = (eval(h) - eval(-h)) / (2 * h);
    }
    INFO(names[which] << ": analytic " << grads[which].view({-1}).slice(0, 0, 8) << " fd "
                      << fd.view({-1}).slice(0, 0, 8));
    CHECK(grads[which].abs().sum().item<double>() > 0.0);
    CHECK(rel_error(grads[which], fd) < 1e-5);
    CHECK((grads[which] - fd).abs().max().item<double>() < 1e-4 * (1.0 + fd.abs().max().item<double>()));
  }
}

// One rasterization on a device and the gradients of the probe.
struct Rendered {
  render::RenderOutput out;
  std::vector<torch::Tensor> grads;  // on the CPU, one per input
};

// Renders fresh leaf copies of `inputs` on `dev` (render moves anything else,
// such as the cameras, there itself).
inline Rendered render_with_grads(const std::vector<torch::Tensor>& inputs, const torch::Device& dev,
                                  const RenderFn& render, const Probe& probe) {
  std::vector<torch::Tensor> in;
  for (const auto& t : inputs) in.push_back(t.to(dev).detach().requires_grad_(true));
  Rendered r;
  r.out = render(in);
  r.grads = torch::autograd::grad({probe(r.out)}, in);
  for (auto& g : r.grads) g = g.cpu();
  return r;
}

// An output of the CUDA kernels against the CPU reference's: relative L2
// error, the elements off by more than 1e-4 (or not finite), and the
// relative L2 error of the others.
struct OutputDiff {
  double rel = 0.0;
  int64_t n_off = 0;
  double rel_rest = 0.0;
};

inline OutputDiff output_diff(const torch::Tensor& got, const torch::Tensor& ref) {
  const torch::Tensor g = got.cpu();
  const auto off = (g - ref).abs().gt(1e-4).logical_or(g.isfinite().logical_not());
  const auto keep = off.logical_not();
  return {rel_error(g, ref), off.sum().item<int64_t>(), rel_error(g.index({keep}), ref.index({keep}))};
}

// A geometry gradient of n primitives against the reference's: the
// primitives whose gradient differs by more than 1e-3 of the reference's
// largest (fragments within rounding of a branch move a few by O(their
// gradient)), and the relative L2 error of the others.
struct GradOutliers {
  int64_t count = 0;
  double rel_rest = 0.0;
};

inline GradOutliers gradient_outliers(const torch::Tensor& got, const torch::Tensor& ref, int64_t n) {
  const auto per_primitive = (got - ref).abs().reshape({n, -1}).amax(1);
  const auto outlier = per_primitive.gt(1e-3 * ref.abs().max().item<double>());
  const auto keep = outlier.logical_not();
  return {outlier.sum().item<int64_t>(), rel_error(got.index({keep}), ref.index({keep}))};
}

// The compositing rules every rasterizer shares, checked on its output.

// A pile of n primitives over the image centre, in index order front to back
// (opacity 0.5 each): the centre pixel saturates but stops before its
// transmittance would fall below the default transmittance_min (1e-4; within
// one step), the front primitive dominates and the deepest gets next to no
// weight.
inline void check_transmittance_floor(const render::RenderOutput& out, int64_t n) {
  const int64_t H = out.alpha.size(2), W = out.alpha.size(3);
  const float a = out.alpha[0][0][H / 2][W / 2].item<float>();
  CHECK(a > 0.999f);
  CHECK(a < 1.0f);
  CHECK(1.0f - a >= 1e-4f * 0.49f);
  CHECK(out.max_weight[0].item<float>() > 0.3f);
  CHECK(out.max_weight[n - 1].item<float>() < 1e-3f);
}

// The background of the empty-scene checks: a colour no channel shares.
inline const std::vector<double> kEmptySceneBackground = {0.1, 0.2, 0.3};

// An empty scene rendered into 2 views of height x width over
// kEmptySceneBackground: the background everywhere, alpha 0, no max_weight,
// and rgb.sum()'s gradient reaches `leaf` (an input that requires grad) with
// its own, empty, shape.
inline void check_empty_scene(const render::RenderOutput& out, int64_t height, int64_t width,
                              const torch::Tensor& leaf) {
  CHECK(out.rgb.sizes() == torch::IntArrayRef({2, 3, height, width}));
  for (int64_t c = 0; c < 3; ++c)
    CHECK(out.rgb.select(1, c).sub(kEmptySceneBackground[c]).abs().max().item<float>() < 1e-7f);
  CHECK(out.alpha.abs().max().item<float>() == 0.0f);
  CHECK(out.max_weight.numel() == 0);
  out.rgb.sum().backward();
  REQUIRE(leaf.grad().defined());
  CHECK(leaf.grad().sizes() == leaf.sizes());
}

// A rasterizer of a fixed scene into given cameras.
using ViewsFn = std::function<render::RenderOutput(const camera::Cameras&)>;

// Rendering all of `cams` at once equals rendering each view alone, bit for
// bit: rgb, depth and (where the rasterizer has it) the distortion.
inline void check_views_independent(const ViewsFn& render, const camera::Cameras& cams) {
  const render::RenderOutput all = render(cams);
  for (int64_t v = 0; v < cams.size(); ++v) {
    const render::RenderOutput one = render(cams.index(torch::tensor({v}, torch::kLong)));
    CHECK(torch::equal(one.rgb[0], all.rgb[v]));
    CHECK(torch::equal(one.depth[0], all.depth[v]));
    if (all.distortion.defined()) CHECK(torch::equal(one.distortion[0], all.distortion[v]));
  }
}

}  // namespace flat::test
