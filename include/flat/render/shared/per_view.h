// The CPU references' per-view compositing, shared by the three rasterizers
// (render/cpu, gaussians/cpu, surfels/cpu): the compositing order, the
// front-to-back loop and its back-to-front replay (3DGS' recurrence), the
// images written from the per-pixel sums, the upstream gradients laid out
// per pixel, the backward over every view and the float/double choice, which
// are the same whatever the primitive. Each primitive
// supplies a small struct with its own maths (its fragment at a pixel, the
// values it composites, its gradient: composite_forward, composite_backward).
// Public, under flat/render/shared/, because the gaussians and surfels
// modules include it; not part of the rasterizer's API.
#pragma once
#include <algorithm>
#include <cstdint>
#include <numeric>
#include <string>
#include <vector>

#include <ATen/ATen.h>

#include "flat/core/error.h"
#include "flat/render/rasterize.h"
#include "flat/render/shared/compositing.h"
#include "flat/render/shared/view_geometry.h"

namespace flat::render::cpu {

// The compositing order of a view's visible primitives from their
// depth_sort_key()s: by key, ties by their order in `keys` (index order), as
// the CUDA radix sort (stable) gives it.
inline std::vector<size_t> depth_order(const std::vector<uint32_t>& keys) {
  std::vector<size_t> order(keys.size());
  std::iota(order.begin(), order.end(), size_t(0));
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return keys[a] < keys[b]; });
  return order;
}

// View `view`'s camera from the host tensors w2c (V,4,4) and K (V,4).
template <class T>
CameraView<T> view_camera(const at::Tensor& w2c, const at::Tensor& K, int64_t view) {
  return make_camera_view(w2c.data_ptr<T>() + view * 16, K.data_ptr<T>() + view * 4);
}

// Primitive n's colour (colors (N,3)) and opacity (opacities (N)) into its
// record's color[3] and opacity.
template <class T, class Record>
void set_appearance(Record& record, const at::Tensor& colors, const at::Tensor& opacities, int64_t n) {
  for (int c = 0; c < 3; ++c) record.color[c] = colors.data_ptr<T>()[3 * n + c];
  record.opacity = opacities.data_ptr<T>()[n];
}

// A view's visible primitives: each one's record (what a pixel needs of it
// in this view), pixel rectangle and input row; add() them in index order,
// then sort() puts them in compositing order.
template <class Record>
struct ViewList {
  std::vector<Record> records;
  std::vector<PixelRect> rects;
  std::vector<int64_t> ids;
  std::vector<uint32_t> keys;  // depth_sort_key(), as the CUDA sort

  void add(const Record& record, const PixelRect& rect, int64_t id, float depth) {
    records.push_back(record);
    rects.push_back(rect);
    ids.push_back(id);
    keys.push_back(depth_sort_key(depth));
  }
  void sort() {
    const std::vector<size_t> order = depth_order(keys);
    ViewList sorted;
    for (size_t i : order) sorted.add_sorted(records[i], rects[i], ids[i], keys[i]);
    *this = std::move(sorted);
  }
  size_t size() const { return records.size(); }

 private:
  void add_sorted(const Record& record, const PixelRect& rect, int64_t id, uint32_t key) {
    records.push_back(record);
    rects.push_back(rect);
    ids.push_back(id);
    keys.push_back(key);
  }
};

// What the forward leaves of one view, per pixel: the final transmittance,
// the number of list entries processed (the last contributor is entry
// last - 1), the channel sums sum_k w_k v_k (`stride` a pixel: r, g, b,
// depth, then the primitive's others) and the median depth.
template <class T>
struct ViewSums {
  int stride = 0;
  std::vector<T> t_final;
  std::vector<int64_t> last;
  std::vector<T> sums;
  std::vector<T> median;
};

// Composites one view's list front to back: skip a fragment that does not
// blend, stop a pixel before its transmittance would drop below t_min. Written
// primitive-major (each entry updates the pixels of its rectangle in list
// order), which is the order in which each pixel meets them. max_weight (by
// input row) gets each primitive's largest blending weight. Prim, the
// primitive's maths in this view, has its ViewList `list` and for list
// entry r:
//   Fragment                    what a pixel computes of it (with .alpha);
//   kSums                       its channels: r, g, b, depth, then its own;
//   fragment(r, x, y, f)        the fragment at pixel (x, y): whether it blends
//                               (fragment_blends() and the primitive's own tests);
//   values(r, f, v)             its kSums channel values at that fragment;
//   blended(p, f, w, t_front, first)  anything more it sums at pixel p (the
//                               fragment's weight w, the transmittance in front
//                               of it, whether it is the pixel's first).
template <class T, class Prim>
ViewSums<T> composite_forward(Prim& prim, int64_t W, int64_t HW, const CompositingConstants& k, T* max_weight) {
  const std::vector<PixelRect>& rects = prim.list.rects;
  const std::vector<int64_t>& ids = prim.list.ids;
  constexpr int C = Prim::kSums;
  ViewSums<T> s;
  s.stride = C;
  s.t_final.assign(HW, T(1));
  s.last.assign(HW, 0);
  s.sums.assign(HW * C, T(0));
  s.median.assign(HW, T(0));
  std::vector<char> done(HW, 0);
  for (size_t r = 0; r < rects.size(); ++r) {
    const PixelRect& rc = rects[r];
    for (int y = rc.y0; y < rc.y1; ++y)
      for (int x = rc.x0; x < rc.x1; ++x) {
        const int64_t p = (int64_t)y * W + x;
        if (done[p]) continue;
        typename Prim::Fragment f;
        if (!prim.fragment(r, x, y, f)) continue;
        T& Tp = s.t_final[p];
        const T test_T = Tp * (T(1) - f.alpha);
        if (stops_before(test_T, k)) {
          done[p] = 1;
          continue;
        }
        const T w = f.alpha * Tp;
        T v[C];
        prim.values(r, f, v);
        T* a = &s.sums[p * C];
        for (int c = 0; c < C; ++c) a[c] += w * v[c];
        if (Tp > T(kMedianTransmittance)) s.median[p] = v[3];
        prim.blended(p, f, w, Tp, s.last[p] == 0);
        max_weight[ids[r]] = std::max(max_weight[ids[r]], w);
        Tp = test_T;
        s.last[p] = (int64_t)r + 1;
      }
  }
  return s;
}

// Writes view `view` of the (V,C,H,W) images from the forward's per-pixel
// sums (r, g, b, depth and, when `normal` is defined, nx, ny, nz at offsets
// 0..6); rgb gets the background behind the final transmittance.
template <class T>
void write_view_images(int64_t view, int64_t HW, const ViewSums<T>& s, const T* bg, const at::Tensor& rgb,
                       const at::Tensor& alpha, const at::Tensor& depth, const at::Tensor& normal,
                       const at::Tensor& median_depth) {
  T* out_rgb = rgb.data_ptr<T>() + view * 3 * HW;
  T* out_alpha = alpha.data_ptr<T>() + view * HW;
  T* out_depth = depth.data_ptr<T>() + view * HW;
  T* out_normal = normal.defined() ? normal.data_ptr<T>() + view * 3 * HW : nullptr;
  T* out_median = median_depth.data_ptr<T>() + view * HW;
  for (int64_t p = 0; p < HW; ++p) {
    const T* a = &s.sums[p * s.stride];
    for (int c = 0; c < 3; ++c) out_rgb[c * HW + p] = a[c] + s.t_final[p] * bg[c];
    out_alpha[p] = T(1) - s.t_final[p];
    out_depth[p] = a[3];
    if (out_normal)
      for (int c = 0; c < 3; ++c) out_normal[c * HW + p] = a[4 + c];
    out_median[p] = s.median[p];
  }
}

// View `view` of the upstream gradients `grads` ((V,C_i,H,W) each, HW
// pixels a view) side by side per pixel, in their order: the backward reads
// a pixel's gradients of every output together (sum C_i values a pixel).
template <class T>
std::vector<T> interleave_grads(const std::vector<at::Tensor>& grads, int64_t view, int64_t HW) {
  int64_t stride = 0;
  for (const at::Tensor& g : grads) stride += g.size(1);
  std::vector<T> G(HW * stride);
  int64_t offset = 0;
  for (const at::Tensor& grad : grads) {
    const int64_t C = grad.size(1);
    const T* g = grad.data_ptr<T>() + view * C * HW;
    for (int64_t p = 0; p < HW; ++p)
      for (int64_t c = 0; c < C; ++c) G[p * stride + offset + c] = g[c * HW + p];
    offset += C;
  }
  return G;
}

// The backward's per-pixel state as it replays one view's fragments back to
// front, C channels a fragment (channels 0..2 are rgb).
template <class T>
struct BackToFront {
  int C;
  std::vector<T> t_final;     // final transmittance
  std::vector<T> t_cur;       // transmittance in front of the fragment last stepped over
  std::vector<T> behind;      // the channels of what lies behind it, composited
  std::vector<T> last_f;      // that fragment's channel values
  std::vector<T> last_alpha;  // and its alpha

  BackToFront(const std::vector<T>& t_final_, int channels)
      : C(channels),
        t_final(t_final_),
        t_cur(t_final_),
        behind(t_final_.size() * channels, T(0)),
        last_f(t_final_.size() * channels, T(0)),
        last_alpha(t_final_.size(), T(0)) {}

  // Steps pixel p back over a fragment of `alpha`: the transmittance in front of it.
  T step(int64_t p, T alpha) {
    t_cur[p] = t_cur[p] / (T(1) - alpha);
    return t_cur[p];
  }

  // dL/dalpha of the fragment just stepped over (Tp: step()'s value), with fv
  // its C channel values and Gp the pixel's C upstream gradients; bg the
  // background (its share falls with the final transmittance).
  T alpha_grad(int64_t p, const T* fv, const T* Gp, T alpha, T Tp, const T* bg) {
    T* ap = &behind[p * C];
    T* lf = &last_f[p * C];
    T g = T(0);
    for (int c = 0; c < C; ++c) {
      ap[c] = last_alpha[p] * lf[c] + (T(1) - last_alpha[p]) * ap[c];
      g += (fv[c] - ap[c]) * Gp[c];
      lf[c] = fv[c];
    }
    g *= Tp;
    const T bgdot = bg[0] * Gp[0] + bg[1] * Gp[1] + bg[2] * Gp[2];
    g += -t_final[p] / (T(1) - alpha) * bgdot;
    last_alpha[p] = alpha;
    return g;
  }
};

// The backward of composite_forward: replays each pixel's fragments back to
// front from the forward's state `fwd`. G holds the upstream gradients,
// Prim::kGrads a pixel (interleave_grads()), of the channels whose values
// Prim::grad_values gives (r, g, b first); bg the background. Prim, as in
// the forward, and for list entry r:
//   start(r)                             entry r's gradient sums start at zero;
//   grad_values(r, p, f, v)              its C channel values at pixel p;
//   add_grad(r, x, y, f, w, g_alpha, Gp) its gradient from pixel (x, y): w its
//                                        weight, g_alpha dL/dalpha, Gp the pixel's G;
//   finish(r)                            it has met all its pixels (chain to the inputs).
template <class T, class Prim>
void composite_backward(Prim& prim, const ViewSums<T>& fwd, int64_t W, const std::vector<T>& G, const T* bg) {
  constexpr int C = Prim::kGrads;
  const std::vector<PixelRect>& rects = prim.list.rects;
  BackToFront<T> replay(fwd.t_final, C);
  T v[C];
  for (int64_t r = (int64_t)rects.size() - 1; r >= 0; --r) {
    const PixelRect& rc = rects[r];
    prim.start(r);
    for (int y = rc.y0; y < rc.y1; ++y)
      for (int x = rc.x0; x < rc.x1; ++x) {
        const int64_t p = (int64_t)y * W + x;
        if (r >= fwd.last[p]) continue;
        typename Prim::Fragment f;
        if (!prim.fragment(r, x, y, f)) continue;
        const T Tp = replay.step(p, f.alpha);  // transmittance in front of this entry
        prim.grad_values(r, p, f, v);
        const T* Gp = &G[p * C];
        const T g_alpha = replay.alpha_grad(p, v, Gp, f.alpha, Tp, bg);
        prim.add_grad(r, x, y, f, f.alpha * Tp, g_alpha, Gp);
      }
    prim.finish(r);
  }
}

// Whether a CPU reference runs in double: float64 inputs do (the finite
// difference tests), float32 ones in float; any other dtype is refused,
// naming the rasterizer.
inline bool runs_in_double(at::ScalarType dtype, const char* rasterizer) {
  if (dtype == at::kDouble) return true;
  FLAT_CHECK(dtype == at::kFloat, std::string(rasterizer) + " (cpu): expected float32 or float64 tensors");
  return false;
}

// forward_views() in T: each view composited, its images written.
template <class T, class Prim, class Inputs>
void forward_views_in(const Inputs& in, RenderOutput& out) {
  const int64_t HW = in.height * in.width;
  const at::Tensor& background = in.background;
  for (int64_t view = 0; view < in.w2c.size(0); ++view) {
    Prim prim(in, view);
    const ViewSums<T> sums = composite_forward<T>(prim, in.width, HW, in.k, out.max_weight.data_ptr<T>());
    write_view_images(view, HW, sums, background.data_ptr<T>(), out.rgb, out.alpha, out.depth, out.normal,
                      out.median_depth);
    prim.write_own_images(view, out);
  }
}

// The forward of every view in turn into `out` (the images, uninitialised;
// normal undefined for a primitive without one), in double or float as the
// primitives' input `rows` (N rows, one a primitive) is; max_weight is made
// here. Prim<T>(in, view) holds a view's visible primitives (composite_forward);
// write_own_images(view, out) writes the images only it has (the surfels'
// distortion). Returns `out`.
template <template <class> class Prim, class Inputs>
RenderOutput forward_views(const Inputs& in, const at::Tensor& rows, RenderOutput out, const char* rasterizer) {
  out.max_weight = at::zeros({rows.size(0)}, rows.options());
  if (runs_in_double(rows.scalar_type(), rasterizer))
    forward_views_in<double, Prim<double>>(in, out);
  else
    forward_views_in<float, Prim<float>>(in, out);
  return out;
}

// backward_views() in T: each view's forward replayed (the state its backward
// starts from), then composite_backward with that view's upstream gradients.
template <class T, class Prim, class Inputs, class Grads>
void backward_views_in(const Inputs& in, int64_t primitives, const std::vector<at::Tensor>& upstream, Grads& grads) {
  const int64_t HW = in.height * in.width;
  const at::Tensor& background = in.background;
  std::vector<T> scratch_max(primitives, T(0));  // the replay's max_weight, not an output
  for (int64_t view = 0; view < in.w2c.size(0); ++view) {
    Prim prim(in, view);
    prim.grads = &grads;
    const ViewSums<T> fwd = composite_forward<T>(prim, in.width, HW, in.k, scratch_max.data());
    prim.forward_done(fwd);
    composite_backward<T>(prim, fwd, in.width, interleave_grads<T>(upstream, view, HW), background.data_ptr<T>());
  }
}

// The backward of every view in turn, summed into `grads` (zeros of the
// inputs' shapes), in double or float as the forward_views(). Prim<T>(in,
// view) holds a view's primitives as in the forward; its `grads` receives the
// inputs' gradients, and forward_done(fwd) hands it the replayed forward's
// state before the backward starts. upstream: the output gradients in Prim's
// channel order (interleave_grads()). Returns `grads`.
template <template <class> class Prim, class Inputs, class Grads>
Grads backward_views(const Inputs& in, const at::Tensor& rows, Grads grads, const std::vector<at::Tensor>& upstream,
                     const char* rasterizer) {
  if (runs_in_double(rows.scalar_type(), rasterizer))
    backward_views_in<double, Prim<double>>(in, rows.size(0), upstream, grads);
  else
    backward_views_in<float, Prim<float>>(in, rows.size(0), upstream, grads);
  return grads;
}

}  // namespace flat::render::cpu
