// CPU reference Gaussian rasterizer. Semantics (shared with the CUDA kernels):
//  - per view, visible Gaussians are sorted by the camera depth of their mean
//    (render::depth_sort_key(): to 2^-16), ties by index (the CUDA radix sort
//    is stable);
//  - each pixel composites them front to back (skipping fragments that
//    shade() rejects: q > 9 or alpha < alpha_min) and the backward replays it
//    back to front: the loops shared by the three rasterizers
//    (flat/render/shared/per_view.h); here the Gaussian's part of them.
#include "gaussians/cpu/raster_gaussians_cpu.h"

#include <algorithm>
#include <vector>

#include "flat/core/error.h"
#include "flat/render/shared/per_view.h"

namespace flat::gaussians::cpu {
namespace {

using render::cpu::composite_backward;
using render::cpu::composite_forward;
using render::cpu::ViewSums;

// One view's Gaussians for composite_forward / composite_backward
// (render/shared/per_view.h): their fragments, the values they composite and
// the chain rule of their gradients.
template <class T>
struct GaussianView {
  using Fragment = gaussians::Fragment<T>;
  static constexpr int kSums = 4;   // r, g, b, depth
  static constexpr int kGrads = 5;  // and alpha

  const GaussianInputs& in;
  CameraView<T> cam;
  render::cpu::ViewList<ScreenGaussian<T>> list;  // visible, in compositing order
  ScreenGrad<T> gr;  // the backward: the entry being replayed's gradient sums
  GaussianGrads* grads = nullptr;

  GaussianView(const GaussianInputs& in_, int64_t view) : in(in_) {
    cam = render::cpu::view_camera<T>(in.w2c, in.K, view);
    const T* m = in.means.data_ptr<T>();
    const T* s = in.scales.data_ptr<T>();
    const T* q = in.rotations.data_ptr<T>();
    const T* op = in.opacities.data_ptr<T>();
    for (int64_t n = 0; n < in.means.size(0); ++n) {
      ScreenGaussian<T> g{};
      PixelBox b;
      if (!preprocess_forward(m + 3 * n, s + 3 * n, q + 4 * n, op[n], cam, in.k, (int)in.width, (int)in.height, g, b))
        continue;
      render::cpu::set_appearance<T>(g, in.colors, in.opacities, n);
      list.add(g, b, n, (float)g.z);
    }
    list.sort();
  }

  bool fragment(size_t r, int x, int y, Fragment& f) const {
    return shade(list.records[r], T(x) + T(0.5), T(y) + T(0.5), in.k, f);
  }
  void values(size_t r, const Fragment&, T* v) const {
    const ScreenGaussian<T>& g = list.records[r];
    v[0] = g.color[0], v[1] = g.color[1], v[2] = g.color[2], v[3] = g.z;
  }
  void blended(int64_t, const Fragment&, T, T, bool) {}

  void start(size_t) { gr = ScreenGrad<T>{}; }
  void grad_values(size_t r, int64_t, const Fragment& f, T* v) const {
    values(r, f, v);
    v[4] = T(1);
  }
  void add_grad(size_t r, int, int, const Fragment& f, T w, T g_alpha, const T* Gp) {
    for (int c = 0; c < 3; ++c) gr.color[c] += w * Gp[c];
    gr.z += w * Gp[3];
    shade_backward(list.records[r], f, in.k, g_alpha, gr);
  }
  // Chains this view's screen-space gradient to the inputs.
  void finish(size_t r) {
    const int64_t n = list.ids[r];
    for (int c = 0; c < 3; ++c) grads->colors.data_ptr<T>()[3 * n + c] += gr.color[c];
    grads->opacities.data_ptr<T>()[n] += gr.opacity;
    preprocess_backward(in.means.data_ptr<T>() + 3 * n, in.scales.data_ptr<T>() + 3 * n,
                        in.rotations.data_ptr<T>() + 4 * n, cam, (int)in.width, (int)in.height, gr,
                        grads->means.data_ptr<T>() + 3 * n, grads->scales.data_ptr<T>() + 3 * n,
                        grads->rotations.data_ptr<T>() + 4 * n);
  }
};

template <class T>
GaussianOutputs forward_impl(const GaussianInputs& in) {
  const int64_t HW = in.height * in.width;
  GaussianOutputs out = images_for(in);
  out.max_weight = at::zeros({in.means.size(0)}, in.means.options());
  for (int64_t v = 0; v < in.w2c.size(0); ++v) {
    GaussianView<T> gv(in, v);
    const ViewSums<T> sums = composite_forward<T>(gv, in.width, HW, in.k, out.max_weight.data_ptr<T>());
    render::cpu::write_view_images(v, HW, sums, in.background.data_ptr<T>(), out.rgb, out.alpha, out.depth,
                                   at::Tensor(), out.median_depth);
  }
  return out;
}

template <class T>
GaussianGrads backward_impl(const GaussianInputs& in, const GaussianOutputGrads& grads) {
  const int64_t HW = in.height * in.width;
  GaussianGrads g = GaussianGrads::zeros_for(in);
  std::vector<T> scratch_max(in.means.size(0), T(0));
  for (int64_t view = 0; view < in.w2c.size(0); ++view) {
    GaussianView<T> gv(in, view);
    gv.grads = &g;
    const ViewSums<T> fwd = composite_forward<T>(gv, in.width, HW, in.k, scratch_max.data());
    // Upstream gradient per pixel and channel (r, g, b, depth, alpha).
    const std::vector<T> G = render::cpu::interleave_grads<T>({grads.rgb, grads.depth, grads.alpha}, view, HW);
    composite_backward<T>(gv, fwd, in.width, G, in.background.data_ptr<T>());
  }
  return g;
}

}  // namespace

GaussianOutputs forward(const GaussianInputs& in) {
  if (in.means.scalar_type() == at::kDouble) return forward_impl<double>(in);
  FLAT_CHECK(in.means.scalar_type() == at::kFloat, "rasterize_gaussians (cpu): expected float32 or float64 tensors");
  return forward_impl<float>(in);
}

GaussianGrads backward(const GaussianInputs& in, const GaussianOutputGrads& grads) {
  if (in.means.scalar_type() == at::kDouble) return backward_impl<double>(in, grads);
  return backward_impl<float>(in, grads);
}

}  // namespace flat::gaussians::cpu
