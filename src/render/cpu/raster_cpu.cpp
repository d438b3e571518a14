// CPU reference rasterizer. Semantics (shared with the CUDA kernels):
//  - per view, visible triangles are sorted by the camera depth of their
//    centroid (depth_sort_key(): to 2^-16), ties by triangle index (the CUDA
//    radix sort is stable);
//  - each pixel composites them front to back: skip alpha < alpha_min, stop
//    before the transmittance would drop below t_min;
//  - the backward replays each pixel back to front (3DGS-style recurrence).
// Written triangle-major (each triangle updates the pixels of its support
// rectangle in depth order), which is the same per-pixel order.
#include "render/cpu/raster_cpu.h"

#include <algorithm>
#include <vector>

#include "flat/core/error.h"
#include "flat/render/shared/per_view.h"

namespace flat::render::cpu {
namespace {

constexpr int kChannels = 8;  // r, g, b, depth, nx, ny, nz, alpha

template <class T>
struct ViewSetup {
  CameraView<T> cam;
  std::vector<PixelTri<T>> tris;  // visible, in compositing order
  std::vector<TriRect> rects;
  std::vector<int64_t> ids;       // triangle index of each entry
};

template <class T>
ViewSetup<T> setup_view(const RasterInputs& in, int64_t view) {
  ViewSetup<T> vs;
  const T* w2c = in.w2c.data_ptr<T>() + view * 16;
  const T* K = in.K.data_ptr<T>() + view * 4;
  vs.cam = make_camera_view(w2c, K);
  const int64_t N = in.vertices.size(0);
  const T* v = in.vertices.data_ptr<T>();
  const T* col = in.colors.data_ptr<T>();
  const T* op = in.opacities.data_ptr<T>();
  const T* sg = in.sigmas.data_ptr<T>();
  std::vector<PixelTri<T>> tris;
  std::vector<TriRect> rects;
  std::vector<int64_t> ids;
  std::vector<uint32_t> keys;  // depth_sort_key(), as the CUDA sort
  for (int64_t n = 0; n < N; ++n) {
    if (in.k.alpha_min > 0.f && !(op[n] >= T(in.k.alpha_min))) continue;  // can never reach alpha_min
    PixelTri<T> t;
    TriRect r;
    T key;
    if (!preprocess_forward(v + 9 * n, vs.cam, in.k, (int)in.width, (int)in.height, t, r, key)) continue;
    for (int c = 0; c < 3; ++c) t.color[c] = col[3 * n + c];
    t.opacity = op[n];
    t.sigma = sg[n];
    tris.push_back(t);
    rects.push_back(r);
    ids.push_back(n);
    keys.push_back(depth_sort_key((float)key));
  }
  for (size_t i : depth_order(keys)) {
    vs.tris.push_back(tris[i]);
    vs.rects.push_back(rects[i]);
    vs.ids.push_back(ids[i]);
  }
  return vs;
}

// Per-pixel state left by the forward: final transmittance and the number of
// list entries processed (the last contributor is entry last - 1).
template <class T>
struct PixelState {
  std::vector<T> t_final;
  std::vector<int64_t> last;
};

template <class T>
PixelState<T> forward_view(const RasterInputs& in, const ViewSetup<T>& vs, int64_t view, const RasterOutputs* out,
                           T* max_weight) {
  const int64_t H = in.height, W = in.width, HW = H * W;
  const RasterConstants& k = in.k;
  PixelState<T> ps;
  ps.t_final.assign(HW, T(1));
  ps.last.assign(HW, 0);
  std::vector<char> done(HW, 0);
  std::vector<T> acc(HW * kChannels, T(0));
  std::vector<T> median(HW, T(0));
  for (size_t r = 0; r < vs.tris.size(); ++r) {
    const PixelTri<T>& t = vs.tris[r];
    const TriRect& rc = vs.rects[r];
    for (int y = rc.y0; y < rc.y1; ++y)
      for (int x = rc.x0; x < rc.x1; ++x) {
        const int64_t p = (int64_t)y * W + x;
        if (done[p]) continue;
        const T px = T(x) + T(0.5), py = T(y) + T(0.5);
        const T rx = (px - vs.cam.cx) / vs.cam.fx, ry = (py - vs.cam.cy) / vs.cam.fy;
        Fragment<T> f;
        shade(t, px, py, rx, ry, k, f);
        if (f.alpha < T(k.alpha_min) || !(f.alpha > T(0))) continue;
        T& Tp = ps.t_final[p];
        const T test_T = Tp * (T(1) - f.alpha);
        if (test_T < T(k.t_min)) {
          done[p] = 1;
          continue;
        }
        fragment_depth(t, rx, ry, f);
        const T w = f.alpha * Tp;
        T* a = &acc[p * kChannels];
        for (int c = 0; c < 3; ++c) a[c] += w * t.color[c];
        a[3] += w * f.z;
        for (int c = 0; c < 3; ++c) a[4 + c] += w * t.normal[c];
        if (Tp > T(0.5)) median[p] = f.z;
        max_weight[vs.ids[r]] = std::max(max_weight[vs.ids[r]], w);
        Tp = test_T;
        ps.last[p] = (int64_t)r + 1;
      }
  }
  if (out)
    write_view_images(view, HW, acc.data(), kChannels, ps.t_final, median, in.background.data_ptr<T>(), out->rgb,
                      out->alpha, out->depth, out->normal, out->median_depth);
  return ps;
}

template <class T>
RasterOutputs forward_impl(const RasterInputs& in) {
  const int64_t V = in.w2c.size(0);
  RasterOutputs out = RasterOutputs::images_for(in);
  out.max_weight = at::zeros({in.vertices.size(0)}, in.vertices.options());
  for (int64_t v = 0; v < V; ++v) {
    const ViewSetup<T> vs = setup_view<T>(in, v);
    forward_view<T>(in, vs, v, &out, out.max_weight.data_ptr<T>());
  }
  return out;
}

template <class T>
RasterGrads backward_impl(const RasterInputs& in, const at::Tensor& g_rgb, const at::Tensor& g_alpha, const at::Tensor& g_depth,
                    const at::Tensor& g_normal) {
  const int64_t V = in.w2c.size(0), H = in.height, W = in.width, HW = H * W;
  const int64_t N = in.vertices.size(0);
  const RasterConstants& k = in.k;
  RasterGrads g = RasterGrads::zeros_for(in);
  T* gv = g.vertices.data_ptr<T>();
  T* gc = g.colors.data_ptr<T>();
  T* go = g.opacities.data_ptr<T>();
  T* gs = g.sigmas.data_ptr<T>();
  const T* bg = in.background.data_ptr<T>();
  const T* v_ptr = in.vertices.data_ptr<T>();
  std::vector<T> scratch_max(N, T(0));
  for (int64_t view = 0; view < V; ++view) {
    const ViewSetup<T> vs = setup_view<T>(in, view);
    const PixelState<T> ps = forward_view<T>(in, vs, view, nullptr, scratch_max.data());
    // Upstream gradient per pixel and channel (r, g, b, depth, nx, ny, nz, alpha).
    std::vector<T> G(HW * kChannels);
    interleave_grad(g_rgb, view, 3, HW, kChannels, 0, G);
    interleave_grad(g_depth, view, 1, HW, kChannels, 3, G);
    interleave_grad(g_normal, view, 3, HW, kChannels, 4, G);
    interleave_grad(g_alpha, view, 1, HW, kChannels, 7, G);
    BackToFront<T> replay(ps.t_final, kChannels);
    std::vector<TriGrad<T>> tg(vs.tris.size());
    for (int64_t r = (int64_t)vs.tris.size() - 1; r >= 0; --r) {
      const PixelTri<T>& t = vs.tris[r];
      const TriRect& rc = vs.rects[r];
      TriGrad<T>& gr = tg[r];
      std::fill(reinterpret_cast<T*>(&gr), reinterpret_cast<T*>(&gr) + kTriGradSize, T(0));
      T g_normal[3] = {T(0), T(0), T(0)};  // folded into gr.h once summed
      for (int y = rc.y0; y < rc.y1; ++y)
        for (int x = rc.x0; x < rc.x1; ++x) {
          const int64_t p = (int64_t)y * W + x;
          if (r >= ps.last[p]) continue;
          const T px = T(x) + T(0.5), py = T(y) + T(0.5);
          const T rx = (px - vs.cam.cx) / vs.cam.fx, ry = (py - vs.cam.cy) / vs.cam.fy;
          Fragment<T> f;
          shade(t, px, py, rx, ry, k, f);
          if (f.alpha < T(k.alpha_min) || !(f.alpha > T(0))) continue;
          fragment_depth(t, rx, ry, f);
          const T Tp = replay.step(p, f.alpha);  // transmittance in front of this triangle
          const T w = f.alpha * Tp;
          const T fv[kChannels] = {t.color[0], t.color[1], t.color[2], f.z,
                                   t.normal[0], t.normal[1], t.normal[2], T(1)};
          const T* Gp = &G[p * kChannels];
          const T g_alpha = replay.alpha_grad(p, fv, Gp, f.alpha, Tp, bg);
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
          if (t.opacity * f.I < T(k.alpha_max)) {  // below the cap alpha = opacity * I
            gr.opacity += g_alpha * f.I;
            T gu[3], gsig;
            window_backward(f.u, t.sigma, T(k.eps), k.window, f.I, g_alpha * t.opacity, gu, gsig);
            gr.sigma += gsig;
            for (int i = 0; i < 3; ++i) {
              gr.n[2 * i] += gu[i] * (px - t.sx);
              gr.n[2 * i + 1] += gu[i] * (py - t.sy);
              gr.s[0] -= gu[i] * t.nx[i];
              gr.s[1] -= gu[i] * t.ny[i];
            }
          }
        }
      fold_normal_grad(t.h, g_normal, gr.h);
      // Chain this view's triangle gradient to the inputs.
      const int64_t n = vs.ids[r];
      for (int c = 0; c < 3; ++c) gc[3 * n + c] += gr.color[c];
      go[n] += gr.opacity;
      gs[n] += gr.sigma;
      preprocess_backward(v_ptr + 9 * n, vs.cam, gr, gv + 9 * n);
    }
  }
  return g;
}

}  // namespace

RasterOutputs forward(const RasterInputs& in) {
  if (in.vertices.scalar_type() == at::kDouble) return forward_impl<double>(in);
  FLAT_CHECK(in.vertices.scalar_type() == at::kFloat, "rasterize (cpu): expected float32 or float64 tensors");
  return forward_impl<float>(in);
}

RasterGrads backward(const RasterInputs& in, const at::Tensor& grad_rgb, const at::Tensor& grad_alpha,
               const at::Tensor& grad_depth, const at::Tensor& grad_normal) {
  if (in.vertices.scalar_type() == at::kDouble)
    return backward_impl<double>(in, grad_rgb, grad_alpha, grad_depth, grad_normal);
  return backward_impl<float>(in, grad_rgb, grad_alpha, grad_depth, grad_normal);
}

}  // namespace flat::render::cpu
