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
  void write_own_images(int64_t, const render::RenderOutput&) const {}
  void forward_done(const ViewSums<T>&) {}

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

}  // namespace

GaussianOutputs forward(const GaussianInputs& in) {
  return render::cpu::forward_views<GaussianView>(in, in.means, images_for(in), "rasterize_gaussians");
}

// Upstream gradient per pixel and channel (r, g, b, depth, alpha).
GaussianGrads backward(const GaussianInputs& in, const GaussianOutputGrads& grads) {
  return render::cpu::backward_views<GaussianView>(in, in.means, GaussianGrads::zeros_for(in),
                                                   {grads.rgb, grads.depth, grads.alpha}, "rasterize_gaussians");
}

}  // namespace flat::gaussians::cpu
