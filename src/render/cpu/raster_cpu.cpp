// CPU reference rasterizer. Semantics (shared with the CUDA kernels):
//  - per view, visible triangles are sorted by the camera depth of their
//    centroid (depth_sort_key(): to 2^-16), ties by triangle index (the CUDA
//    radix sort is stable);
//  - each pixel composites them front to back and the backward replays it
//    back to front: the loops shared by the three rasterizers
//    (flat/render/shared/per_view.h); here the triangle's part of them.
#include "render/cpu/raster_cpu.h"

#include <algorithm>
#include <vector>

#include "flat/core/error.h"
#include "flat/render/shared/per_view.h"

namespace flat::render::cpu {
namespace {

// One view's triangles for composite_forward / composite_backward
// (per_view.h): their fragments, the values they composite and the chain
// rule of their gradients.
template <class T>
struct TriangleView {
  using Fragment = render::Fragment<T>;
  static constexpr int kSums = 7;   // r, g, b, depth, nx, ny, nz
  static constexpr int kGrads = 8;  // and alpha

  const RasterInputs& in;
  CameraView<T> cam;
  ViewList<PixelTri<T>> list;  // visible, in compositing order
  // The backward: the entry being replayed's gradient sums, and where it goes.
  TriGrad<T> gr;
  T g_normal[3];  // folded into gr.h once summed
  RasterGrads* grads = nullptr;

  TriangleView(const RasterInputs& in_, int64_t view) : in(in_) {
    cam = view_camera<T>(in.w2c, in.K, view);
    const T* v = in.vertices.data_ptr<T>();
    const T* op = in.opacities.data_ptr<T>();
    for (int64_t n = 0; n < in.vertices.size(0); ++n) {
      if (!opacity_can_blend(op[n], in.k)) continue;
      PixelTri<T> t;
      TriRect r;
      T key;
      if (!preprocess_forward(v + 9 * n, cam, in.k, (int)in.width, (int)in.height, t, r, key)) continue;
      set_appearance<T>(t, in.colors, in.opacities, n);
      t.sigma = in.sigmas.data_ptr<T>()[n];
      list.add(t, r, n, (float)key);
    }
    list.sort();
  }

  // Pixel (x, y)'s centre and camera ray (x, y; z = 1).
  void ray(int x, int y, T& px, T& py, T& rx, T& ry) const {
    px = T(x) + T(0.5), py = T(y) + T(0.5);
    rx = (px - cam.cx) / cam.fx, ry = (py - cam.cy) / cam.fy;
  }
  bool fragment(size_t r, int x, int y, Fragment& f) const {
    T px, py, rx, ry;
    ray(x, y, px, py, rx, ry);
    shade(list.records[r], px, py, rx, ry, in.k, f);
    if (!fragment_blends(f.alpha, in.k)) return false;
    fragment_depth(list.records[r], rx, ry, f);
    return true;
  }
  void values(size_t r, const Fragment& f, T* v) const {
    const PixelTri<T>& t = list.records[r];
    v[0] = t.color[0], v[1] = t.color[1], v[2] = t.color[2], v[3] = f.z;
    v[4] = t.normal[0], v[5] = t.normal[1], v[6] = t.normal[2];
  }
  void blended(int64_t, const Fragment&, T, T, bool) {}
  void write_own_images(int64_t, const RenderOutput&) const {}
  void forward_done(const ViewSums<T>&) {}

  void start(size_t) {
    std::fill(reinterpret_cast<T*>(&gr), reinterpret_cast<T*>(&gr) + kTriGradSize, T(0));
    g_normal[0] = g_normal[1] = g_normal[2] = T(0);
  }
  void grad_values(size_t r, int64_t, const Fragment& f, T* v) const {
    values(r, f, v);
    v[7] = T(1);
  }
  void add_grad(size_t r, int x, int y, const Fragment& f, T w, T g_alpha, const T* Gp) {
    const PixelTri<T>& t = list.records[r];
    T px, py, rx, ry;
    ray(x, y, px, py, rx, ry);
    for (int c = 0; c < 3; ++c) gr.color[c] += w * Gp[c], g_normal[c] += w * Gp[4 + c];
    const T g_z = w * Gp[3];
    if (f.zclamp == 0) {
      const T g_invz = -g_z * f.z * f.z;
      gr.h[0] += g_invz * rx, gr.h[1] += g_invz * ry, gr.h[2] += g_invz;
    } else if (f.zclamp < 0) {
      gr.zlo += g_z;
    } else {
      gr.zhi += g_z;
    }
    if (!below_alpha_cap(t.opacity, f.I, in.k)) return;  // alpha = opacity * I only below the cap
    gr.opacity += g_alpha * f.I;
    T gu[3], gsig;
    window_backward(f.u, t.sigma, T(in.k.eps), in.k.window, f.I, g_alpha * t.opacity, gu, gsig);
    gr.sigma += gsig;
    for (int i = 0; i < 3; ++i) {
      gr.n[2 * i] += gu[i] * (px - t.sx);
      gr.n[2 * i + 1] += gu[i] * (py - t.sy);
      gr.s[0] -= gu[i] * t.nx[i];
      gr.s[1] -= gu[i] * t.ny[i];
    }
  }
  // Chains this view's triangle gradient to the inputs.
  void finish(size_t r) {
    fold_normal_grad(list.records[r].h, g_normal, gr.h);
    const int64_t n = list.ids[r];
    for (int c = 0; c < 3; ++c) grads->colors.data_ptr<T>()[3 * n + c] += gr.color[c];
    grads->opacities.data_ptr<T>()[n] += gr.opacity;
    grads->sigmas.data_ptr<T>()[n] += gr.sigma;
    preprocess_backward(in.vertices.data_ptr<T>() + 9 * n, cam, gr, grads->vertices.data_ptr<T>() + 9 * n);
  }
};

}  // namespace

RasterOutputs forward(const RasterInputs& in) {
  return forward_views<TriangleView>(in, in.vertices, images_for(in), "rasterize");
}

// Upstream gradient per pixel and channel (r, g, b, depth, nx, ny, nz, alpha).
RasterGrads backward(const RasterInputs& in, const at::Tensor& grad_rgb, const at::Tensor& grad_alpha,
                     const at::Tensor& grad_depth, const at::Tensor& grad_normal) {
  return backward_views<TriangleView>(in, in.vertices, RasterGrads::zeros_for(in),
                                      {grad_rgb, grad_depth, grad_normal, grad_alpha}, "rasterize");
}

}  // namespace flat::render::cpu
