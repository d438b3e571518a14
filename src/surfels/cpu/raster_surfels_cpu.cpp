// CPU reference surfel rasterizer. Semantics (shared with the CUDA kernels):
//  - per view, visible surfels are sorted by the camera depth of their centre
//    (render::depth_sort_key(): to 2^-16), ties by surfel index (the CUDA
//    radix sort is stable);
//  - each pixel composites them front to back: skip fragments that do not
//    blend (shade()), stop before the transmittance would drop below t_min;
//  - the depth distortion is accumulated as 2DGS does, sum_i w_i (m_i^2 A_i +
//    M2_i - 2 m_i M1_i) with A, M1, M2 the sums of w, w m, w m^2 in front,
//    with m measured from the pixel's first blended m (the sum is invariant
//    under a shift of m, and the shift keeps float from cancelling);
//  - the backward replays each pixel back to front (3DGS-style recurrence).
//    The distortion D = 1/2 sum_ij w_i w_j (m_i - m_j)^2 enters it as one
//    more channel: dD/dw_i = m_i^2 W - 2 m_i M1 + M2 and dD/dm_i = 2 w_i
//    (m_i W - M1), with W, M1, M2 the pixel's totals.
// Written surfel-major (each surfel updates the pixels of its support box in
// depth order), which is the same per-pixel order.
#include "surfels/cpu/raster_surfels_cpu.h"

#include <algorithm>
#include <vector>

#include "flat/core/error.h"
#include "flat/render/shared/per_view.h"

namespace flat::surfels::cpu {
namespace {

// r, g, b, depth, nx, ny, nz, alpha, distortion
constexpr int kChannels = 9;

template <class T>
struct ViewSetup {
  CameraView<T> cam;
  std::vector<PixelSurfel<T>> surfels;  // visible, in compositing order
  std::vector<SurfelRect> rects;
};

template <class T>
ViewSetup<T> setup_view(const SurfelInputs& in, int64_t view) {
  ViewSetup<T> vs;
  vs.cam = render::make_camera_view(in.w2c.data_ptr<T>() + view * 16, in.K.data_ptr<T>() + view * 4);
  const int64_t N = in.means.size(0);
  const T* mean = in.means.data_ptr<T>();
  const T* scale = in.scales.data_ptr<T>();
  const T* quat = in.rotations.data_ptr<T>();
  const T* col = in.colors.data_ptr<T>();
  const T* op = in.opacities.data_ptr<T>();
  std::vector<PixelSurfel<T>> surfels;
  std::vector<SurfelRect> rects;
  std::vector<uint32_t> keys;  // depth_sort_key(), as the CUDA sort
  for (int64_t n = 0; n < N; ++n) {
    PixelSurfel<T> s;
    SurfelRect r;
    T key;
    if (!preprocess_forward(mean + 3 * n, scale + 2 * n, quat + 4 * n, op[n], vs.cam, in.k, (int)in.width,
                            (int)in.height, s, r, key))
      continue;
    for (int c = 0; c < 3; ++c) s.color[c] = col[3 * n + c];
    s.opacity = op[n];
    s.index = (int32_t)n;
    surfels.push_back(s);
    rects.push_back(r);
    keys.push_back(render::depth_sort_key((float)key));
  }
  for (size_t i : render::cpu::depth_order(keys)) {
    vs.surfels.push_back(surfels[i]);
    vs.rects.push_back(rects[i]);
  }
  return vs;
}

// Per-pixel state left by the forward: final transmittance, the number of
// list entries processed (the last contributor is entry last - 1), and the
// distortion's totals: the reference m and the sums of w m, w m^2 (m from it).
template <class T>
struct PixelState {
  std::vector<T> t_final, m_ref, m1, m2;
  std::vector<int64_t> last;
};

template <class T>
PixelState<T> forward_view(const SurfelInputs& in, const ViewSetup<T>& vs, int64_t view, const SurfelOutputs* out,
                           T* max_weight) {
  const int64_t W = in.width, HW = in.height * in.width;
  const RasterConstants& k = in.k;
  PixelState<T> ps;
  ps.t_final.assign(HW, T(1));
  ps.m_ref.assign(HW, T(0));
  ps.m1.assign(HW, T(0));
  ps.m2.assign(HW, T(0));
  ps.last.assign(HW, 0);
  std::vector<char> done(HW, 0);
  std::vector<T> acc(HW * 7, T(0)), median(HW, T(0)), dist(HW, T(0));
  for (size_t r = 0; r < vs.surfels.size(); ++r) {
    const PixelSurfel<T>& s = vs.surfels[r];
    const SurfelRect& rc = vs.rects[r];
    for (int y = rc.y0; y < rc.y1; ++y)
      for (int x = rc.x0; x < rc.x1; ++x) {
        const int64_t p = (int64_t)y * W + x;
        if (done[p]) continue;
        SurfelFragment<T> f;
        if (!shade(s, T(x) + T(0.5), T(y) + T(0.5), k, f)) continue;
        T& Tp = ps.t_final[p];
        const T test_T = Tp * (T(1) - f.alpha);
        if (test_T < T(k.t_min)) {
          done[p] = 1;
          continue;
        }
        const T w = f.alpha * Tp;
        T* a = &acc[p * 7];
        for (int c = 0; c < 3; ++c) a[c] += w * s.color[c], a[4 + c] += w * s.normal[c];
        a[3] += w * f.z;
        if (Tp > T(0.5)) median[p] = f.z;
        if (ps.last[p] == 0) ps.m_ref[p] = ndc_depth(f.z);
        const T m = ndc_depth(f.z) - ps.m_ref[p];
        dist[p] += w * (m * m * (T(1) - Tp) + ps.m2[p] - T(2) * m * ps.m1[p]);
        ps.m1[p] += w * m;
        ps.m2[p] += w * m * m;
        max_weight[s.index] = std::max(max_weight[s.index], w);
        Tp = test_T;
        ps.last[p] = (int64_t)r + 1;
      }
  }
  if (out) {
    render::cpu::write_view_images(view, HW, acc.data(), 7, ps.t_final, median, in.background.data_ptr<T>(), out->rgb,
                                   out->alpha, out->depth, out->normal, out->median_depth);
    std::copy(dist.begin(), dist.end(), out->distortion.data_ptr<T>() + view * HW);
  }
  return ps;
}

template <class T>
SurfelOutputs forward_impl(const SurfelInputs& in) {
  SurfelOutputs out = SurfelOutputs::images_for(in);
  out.max_weight = at::zeros({in.means.size(0)}, in.means.options());
  for (int64_t v = 0; v < in.w2c.size(0); ++v) {
    const ViewSetup<T> vs = setup_view<T>(in, v);
    forward_view<T>(in, vs, v, &out, out.max_weight.data_ptr<T>());
  }
  return out;
}

template <class T>
SurfelGrads backward_impl(const SurfelInputs& in, const SurfelOutputGrads& grads) {
  const int64_t V = in.w2c.size(0), W = in.width, HW = in.height * in.width;
  const RasterConstants& k = in.k;
  SurfelGrads g = SurfelGrads::zeros_for(in);
  T* g_mean = g.means.data_ptr<T>();
  T* g_scale = g.scales.data_ptr<T>();
  T* g_quat = g.rotations.data_ptr<T>();
  T* g_color = g.colors.data_ptr<T>();
  T* g_opacity = g.opacities.data_ptr<T>();
  const T* mean = in.means.data_ptr<T>();
  const T* scale = in.scales.data_ptr<T>();
  const T* quat = in.rotations.data_ptr<T>();
  const T* bg = in.background.data_ptr<T>();
  std::vector<T> scratch_max(in.means.size(0), T(0));
  for (int64_t view = 0; view < V; ++view) {
    const ViewSetup<T> vs = setup_view<T>(in, view);
    const PixelState<T> ps = forward_view<T>(in, vs, view, nullptr, scratch_max.data());
    // Upstream gradient per pixel and channel (r, g, b, depth, nx, ny, nz, alpha, distortion).
    std::vector<T> G(HW * kChannels);
    render::cpu::interleave_grad(grads.rgb, view, 3, HW, kChannels, 0, G);
    render::cpu::interleave_grad(grads.depth, view, 1, HW, kChannels, 3, G);
    render::cpu::interleave_grad(grads.normal, view, 3, HW, kChannels, 4, G);
    render::cpu::interleave_grad(grads.alpha, view, 1, HW, kChannels, 7, G);
    render::cpu::interleave_grad(grads.distortion, view, 1, HW, kChannels, 8, G);
    render::cpu::BackToFront<T> replay(ps.t_final, kChannels);
    for (int64_t r = (int64_t)vs.surfels.size() - 1; r >= 0; --r) {
      const PixelSurfel<T>& s = vs.surfels[r];
      const SurfelRect& rc = vs.rects[r];
      SurfelGrad<T> gr;
      std::fill(reinterpret_cast<T*>(&gr), reinterpret_cast<T*>(&gr) + kSurfelGradSize, T(0));
      for (int y = rc.y0; y < rc.y1; ++y)
        for (int x = rc.x0; x < rc.x1; ++x) {
          const int64_t p = (int64_t)y * W + x;
          if (r >= ps.last[p]) continue;
          const T px = T(x) + T(0.5), py = T(y) + T(0.5);
          SurfelFragment<T> f;
          if (!shade(s, px, py, k, f)) continue;
          const T Tp = replay.step(p, f.alpha);  // transmittance in front of this surfel
          const T w = f.alpha * Tp;
          const T w_total = T(1) - ps.t_final[p];
          const T m = ndc_depth(f.z) - ps.m_ref[p];
          const T fv[kChannels] = {s.color[0],  s.color[1],  s.color[2], f.z, s.normal[0], s.normal[1],
                                   s.normal[2], T(1),        m * m * w_total - T(2) * m * ps.m1[p] + ps.m2[p]};
          const T* Gp = &G[p * kChannels];
          const T g_alpha = replay.alpha_grad(p, fv, Gp, f.alpha, Tp, bg);
          for (int c = 0; c < 3; ++c) gr.color[c] += w * Gp[c], gr.normal[c] += w * Gp[4 + c];
          const T g_z = w * Gp[3] + Gp[8] * T(2) * w * (m * w_total - ps.m1[p]) * ndc_depth_grad(f.z);
          fragment_backward(s, px, py, f, g_alpha, g_z, k, gr);
        }
      // Chain this view's surfel gradient to the inputs.
      const int64_t n = s.index;
      for (int c = 0; c < 3; ++c) g_color[3 * n + c] += gr.color[c];
      g_opacity[n] += gr.opacity;
      preprocess_backward(mean + 3 * n, scale + 2 * n, quat + 4 * n, vs.cam, gr, g_mean + 3 * n, g_scale + 2 * n,
                          g_quat + 4 * n);
    }
  }
  return g;
}

}  // namespace

SurfelOutputs forward(const SurfelInputs& in) {
  if (in.means.scalar_type() == at::kDouble) return forward_impl<double>(in);
  FLAT_CHECK(in.means.scalar_type() == at::kFloat, "rasterize_surfels (cpu): expected float32 or float64 tensors");
  return forward_impl<float>(in);
}

SurfelGrads backward(const SurfelInputs& in, const SurfelOutputGrads& grads) {
  if (in.means.scalar_type() == at::kDouble) return backward_impl<double>(in, grads);
  return backward_impl<float>(in, grads);
}

}  // namespace flat::surfels::cpu
