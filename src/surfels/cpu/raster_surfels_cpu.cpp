// CPU reference surfel rasterizer. Semantics (shared with the CUDA kernels):
//  - per view, visible surfels are sorted by the camera depth of their centre
//    (render::depth_sort_key(): to 2^-16), ties by surfel index (the CUDA
//    radix sort is stable);
//  - each pixel composites them front to back (skipping fragments that do
//    not blend, shade()) and the backward replays it back to front: the
//    loops shared by the three rasterizers (flat/render/shared/per_view.h);
//    here the surfel's part of them;
//  - the depth distortion is accumulated as 2DGS does, sum_i w_i (m_i^2 A_i +
//    M2_i - 2 m_i M1_i) with A, M1, M2 the sums of w, w m, w m^2 in front,
//    with m measured from the pixel's first blended m (the sum is invariant
//    under a shift of m, and the shift keeps float from cancelling);
//  - the distortion D = 1/2 sum_ij w_i w_j (m_i - m_j)^2 enters the backward as one
//    more channel: dD/dw_i = m_i^2 W - 2 m_i M1 + M2 and dD/dm_i = 2 w_i
//    (m_i W - M1), with W, M1, M2 the pixel's totals.
#include "surfels/cpu/raster_surfels_cpu.h"

#include <algorithm>
#include <vector>

#include "flat/core/error.h"
#include "flat/render/shared/per_view.h"

namespace flat::surfels::cpu {
namespace {

using render::cpu::ViewSums;

// One view's surfels for composite_forward / composite_backward
// (render/shared/per_view.h): their fragments, the values they composite,
// the depth distortion and the chain rule of their gradients.
template <class T>
struct SurfelView {
  using Fragment = SurfelFragment<T>;
  static constexpr int kSums = 7;   // r, g, b, depth, nx, ny, nz
  static constexpr int kGrads = 9;  // and alpha, distortion

  const SurfelInputs& in;
  CameraView<T> cam;
  render::cpu::ViewList<PixelSurfel<T>> list;  // visible, in compositing order
  // The distortion per pixel: the reference m and the sums of w m, w m^2
  // (m from it), and the distortion itself.
  std::vector<T> m_ref, m1, m2, dist;
  // The backward: the forward's final transmittance, the entry being
  // replayed's gradient sums, and where they go.
  const std::vector<T>* t_final = nullptr;
  SurfelGrad<T> gr;
  SurfelGrads* grads = nullptr;

  SurfelView(const SurfelInputs& in_, int64_t view) : in(in_) {
    const int64_t HW = in.height * in.width;
    m_ref.assign(HW, T(0));
    m1.assign(HW, T(0));
    m2.assign(HW, T(0));
    dist.assign(HW, T(0));
    cam = render::cpu::view_camera<T>(in.w2c, in.K, view);
    const T* mean = in.means.data_ptr<T>();
    const T* scale = in.scales.data_ptr<T>();
    const T* quat = in.rotations.data_ptr<T>();
    for (int64_t n = 0; n < in.means.size(0); ++n) {
      PixelSurfel<T> s;
      SurfelRect r;
      T key;
      if (!preprocess_forward(mean + 3 * n, scale + 2 * n, quat + 4 * n, in.opacities.data_ptr<T>()[n], cam, in.k,
                              (int)in.width, (int)in.height, s, r, key))
        continue;
      render::cpu::set_appearance<T>(s, in.colors, in.opacities, n);
      s.index = (int32_t)n;
      list.add(s, r, n, (float)key);
    }
    list.sort();
  }

  bool fragment(size_t r, int x, int y, Fragment& f) const {
    return shade(list.records[r], T(x) + T(0.5), T(y) + T(0.5), in.k, f);
  }
  void values(size_t r, const Fragment& f, T* v) const {
    const PixelSurfel<T>& s = list.records[r];
    v[0] = s.color[0], v[1] = s.color[1], v[2] = s.color[2], v[3] = f.z;
    v[4] = s.normal[0], v[5] = s.normal[1], v[6] = s.normal[2];
  }
  // The distortion's running sums (2DGS): w (m^2 A + M2 - 2 m M1), A, M1, M2
  // the sums of w, w m, w m^2 in front (A = 1 - t_front), m from the pixel's
  // first blended m.
  void blended(int64_t p, const Fragment& f, T w, T t_front, bool first) {
    if (first) m_ref[p] = ndc_depth(f.z);
    const T m = ndc_depth(f.z) - m_ref[p];
    dist[p] += w * (m * m * (T(1) - t_front) + m2[p] - T(2) * m * m1[p]);
    m1[p] += w * m;
    m2[p] += w * m * m;
  }
  void write_own_images(int64_t view, const render::RenderOutput& out) const {
    std::copy(dist.begin(), dist.end(), out.distortion.data_ptr<T>() + view * in.height * in.width);
  }
  // The backward reads the forward's final transmittance (the distortion's A).
  void forward_done(const ViewSums<T>& fwd) { t_final = &fwd.t_final; }

  void start(size_t) {
    std::fill(reinterpret_cast<T*>(&gr), reinterpret_cast<T*>(&gr) + kSurfelGradSize, T(0));
  }
  // The distortion's channel value is dD/dw_i = m_i^2 W - 2 m_i M1 + M2 (W,
  // M1, M2 the pixel's totals).
  void grad_values(size_t r, int64_t p, const Fragment& f, T* v) const {
    values(r, f, v);
    const T m = ndc_depth(f.z) - m_ref[p];
    v[7] = T(1);
    v[8] = m * m * (T(1) - (*t_final)[p]) - T(2) * m * m1[p] + m2[p];
  }
  // dD/dm_i = 2 w_i (m_i W - M1) reaches the fragment's depth.
  void add_grad(size_t r, int x, int y, const Fragment& f, T w, T g_alpha, const T* Gp) {
    const int64_t p = (int64_t)y * in.width + x;
    const PixelSurfel<T>& s = list.records[r];
    const T m = ndc_depth(f.z) - m_ref[p];
    for (int c = 0; c < 3; ++c) gr.color[c] += w * Gp[c], gr.normal[c] += w * Gp[4 + c];
    const T g_z = w * Gp[3] + Gp[8] * T(2) * w * (m * (T(1) - (*t_final)[p]) - m1[p]) * ndc_depth_grad(f.z);
    fragment_backward(s, T(x) + T(0.5), T(y) + T(0.5), f, g_alpha, g_z, in.k, gr);
  }
  // Chains this view's surfel gradient to the inputs.
  void finish(size_t r) {
    const int64_t n = list.ids[r];
    for (int c = 0; c < 3; ++c) grads->colors.data_ptr<T>()[3 * n + c] += gr.color[c];
    grads->opacities.data_ptr<T>()[n] += gr.opacity;
    preprocess_backward(in.means.data_ptr<T>() + 3 * n, in.scales.data_ptr<T>() + 2 * n,
                        in.rotations.data_ptr<T>() + 4 * n, cam, gr, grads->means.data_ptr<T>() + 3 * n,
                        grads->scales.data_ptr<T>() + 2 * n, grads->rotations.data_ptr<T>() + 4 * n);
  }
};

}  // namespace

SurfelOutputs forward(const SurfelInputs& in) {
  return render::cpu::forward_views<SurfelView>(in, in.means, images_for(in), "rasterize_surfels");
}

// Upstream gradient per pixel and channel (r, g, b, depth, nx, ny, nz, alpha, distortion).
SurfelGrads backward(const SurfelInputs& in, const SurfelOutputGrads& grads) {
  return render::cpu::backward_views<SurfelView>(
      in, in.means, SurfelGrads::zeros_for(in),
      {grads.rgb, grads.depth, grads.normal, grads.alpha, grads.distortion}, "rasterize_surfels");
}

}  // namespace flat::surfels::cpu
