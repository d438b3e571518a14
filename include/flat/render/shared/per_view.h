// Per-view scaffolding shared by the three CPU references (render/cpu,
// gaussians/cpu, surfels/cpu) around their primitive-specific maths: the
// compositing order, the images written from the per-pixel sums, the
// upstream gradients laid out per pixel, and the backward's back-to-front
// replay (3DGS' recurrence), which is the same whatever the primitive.
// Public, under flat/render/shared/, because the gaussians and surfels
// modules include it; not part of the rasterizer's API.
#pragma once
#include <algorithm>
#include <cstdint>
#include <numeric>
#include <vector>

#include <ATen/ATen.h>

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

// Writes view `view` of the (V,C,H,W) images from the forward's per-pixel
// sums: acc holds r, g, b, depth and (when `normal` is defined) nx, ny, nz at
// offsets 0..6 of `stride` values a pixel; rgb gets the background behind the
// final transmittance t_final.
template <class T>
void write_view_images(int64_t view, int64_t HW, const T* acc, int stride, const std::vector<T>& t_final,
                       const std::vector<T>& median, const T* bg, const at::Tensor& rgb, const at::Tensor& alpha,
                       const at::Tensor& depth, const at::Tensor& normal, const at::Tensor& median_depth) {
  T* out_rgb = rgb.data_ptr<T>() + view * 3 * HW;
  T* out_alpha = alpha.data_ptr<T>() + view * HW;
  T* out_depth = depth.data_ptr<T>() + view * HW;
  T* out_normal = normal.defined() ? normal.data_ptr<T>() + view * 3 * HW : nullptr;
  T* out_median = median_depth.data_ptr<T>() + view * HW;
  for (int64_t p = 0; p < HW; ++p) {
    const T* a = acc + p * stride;
    for (int c = 0; c < 3; ++c) out_rgb[c * HW + p] = a[c] + t_final[p] * bg[c];
    out_alpha[p] = T(1) - t_final[p];
    out_depth[p] = a[3];
    if (out_normal)
      for (int c = 0; c < 3; ++c) out_normal[c * HW + p] = a[4 + c];
    out_median[p] = median[p];
  }
}

// Copies the C planes of view `view` of an upstream gradient grad (V,C,H,W)
// into G, `stride` values a pixel, at offsets offset .. offset + C - 1: the
// backward reads a pixel's gradients of every output side by side.
template <class T>
void interleave_grad(const at::Tensor& grad, int64_t view, int C, int64_t HW, int stride, int offset,
                     std::vector<T>& G) {
  const T* g = grad.data_ptr<T>() + view * C * HW;
  for (int64_t p = 0; p < HW; ++p)
    for (int c = 0; c < C; ++c) G[p * stride + offset + c] = g[c * HW + p];
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

}  // namespace flat::render::cpu
