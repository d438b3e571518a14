// CPU reference Gaussian rasterizer. Semantics (shared with the CUDA kernels):
//  - per view, visible Gaussians are sorted by the camera depth of their mean
//    (render::depth_sort_key(): to 2^-16), ties by index (the CUDA radix sort
//    is stable);
//  - each pixel composites them front to back: skip fragments that shade()
//    rejects (q > 9 or alpha < alpha_min), stop before the transmittance
//    would drop below t_min;
//  - the backward replays each pixel back to front (3DGS recurrence).
// Written Gaussian-major (each Gaussian updates the pixels of its box in
// depth order), which is the same per-pixel order.
#include "gaussians/cpu/raster_gaussians_cpu.h"

#include <algorithm>
#include <vector>

#include "flat/core/error.h"
#include "flat/render/shared/per_view.h"

namespace flat::gaussians::cpu {
namespace {

constexpr int kChannels = 5;  // r, g, b, depth, alpha

template <class T>
struct ViewSetup {
  CameraView<T> cam;
  std::vector<ScreenGaussian<T>> gaussians;  // visible, in compositing order
  std::vector<PixelBox> boxes;
  std::vector<int64_t> ids;  // Gaussian index of each entry
};

template <class T>
ViewSetup<T> setup_view(const GaussianInputs& in, int64_t view) {
  ViewSetup<T> vs;
  vs.cam = make_camera_view(in.w2c.data_ptr<T>() + view * 16, in.K.data_ptr<T>() + view * 4);
  const int64_t N = in.means.size(0);
  const T* m = in.means.data_ptr<T>();
  const T* s = in.scales.data_ptr<T>();
  const T* q = in.rotations.data_ptr<T>();
  const T* col = in.colors.data_ptr<T>();
  const T* op = in.opacities.data_ptr<T>();
  std::vector<ScreenGaussian<T>> gs;
  std::vector<PixelBox> boxes;
  std::vector<int64_t> ids;
  std::vector<uint32_t> keys;  // render::depth_sort_key(), as the CUDA sort
  for (int64_t n = 0; n < N; ++n) {
    ScreenGaussian<T> g{};
    PixelBox b;
    if (!preprocess_forward(m + 3 * n, s + 3 * n, q + 4 * n, op[n], vs.cam, in.k, (int)in.width, (int)in.height, g, b))
      continue;
    for (int c = 0; c < 3; ++c) g.color[c] = col[3 * n + c];
    g.opacity = op[n];
    gs.push_back(g);
    boxes.push_back(b);
    ids.push_back(n);
    keys.push_back(render::depth_sort_key((float)g.z));
  }
  for (size_t i : render::cpu::depth_order(keys)) {
    vs.gaussians.push_back(gs[i]);
    vs.boxes.push_back(boxes[i]);
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
PixelState<T> forward_view(const GaussianInputs& in, const ViewSetup<T>& vs, int64_t view, const GaussianOutputs* out,
                           T* max_weight) {
  const int64_t H = in.height, W = in.width, HW = H * W;
  const GaussianConstants& k = in.k;
  PixelState<T> ps;
  ps.t_final.assign(HW, T(1));
  ps.last.assign(HW, 0);
  std::vector<char> done(HW, 0);
  std::vector<T> acc(HW * 4, T(0));  // r, g, b, depth
  std::vector<T> median(HW, T(0));
  for (size_t r = 0; r < vs.gaussians.size(); ++r) {
    const ScreenGaussian<T>& g = vs.gaussians[r];
    const PixelBox& b = vs.boxes[r];
    for (int y = b.y0; y < b.y1; ++y)
      for (int x = b.x0; x < b.x1; ++x) {
        const int64_t p = (int64_t)y * W + x;
        if (done[p]) continue;
        Fragment<T> f;
        if (!shade(g, T(x) + T(0.5), T(y) + T(0.5), k, f)) continue;
        T& Tp = ps.t_final[p];
        const T test_T = Tp * (T(1) - f.alpha);
        if (test_T < T(k.t_min)) {
          done[p] = 1;
          continue;
        }
        const T w = f.alpha * Tp;
        T* a = &acc[p * 4];
        for (int c = 0; c < 3; ++c) a[c] += w * g.color[c];
        a[3] += w * g.z;
        if (Tp > T(0.5)) median[p] = g.z;
        max_weight[vs.ids[r]] = std::max(max_weight[vs.ids[r]], w);
        Tp = test_T;
        ps.last[p] = (int64_t)r + 1;
      }
  }
  if (out)
    render::cpu::write_view_images(view, HW, acc.data(), 4, ps.t_final, median, in.background.data_ptr<T>(), out->rgb,
                                   out->alpha, out->depth, at::Tensor(), out->median_depth);
  return ps;
}

template <class T>
GaussianOutputs forward_impl(const GaussianInputs& in) {
  const int64_t V = in.w2c.size(0);
  GaussianOutputs out = GaussianOutputs::images_for(in);
  out.max_weight = at::zeros({in.means.size(0)}, in.means.options());
  for (int64_t v = 0; v < V; ++v) {
    const ViewSetup<T> vs = setup_view<T>(in, v);
    forward_view<T>(in, vs, v, &out, out.max_weight.data_ptr<T>());
  }
  return out;
}

template <class T>
GaussianGrads backward_impl(const GaussianInputs& in, const at::Tensor& g_rgb, const at::Tensor& g_alpha,
                            const at::Tensor& g_depth) {
  const int64_t V = in.w2c.size(0), H = in.height, W = in.width, HW = H * W;
  const int64_t N = in.means.size(0);
  const GaussianConstants& k = in.k;
  GaussianGrads g = GaussianGrads::zeros_for(in);
  T* gm = g.means.data_ptr<T>();
  T* gs = g.scales.data_ptr<T>();
  T* gq = g.rotations.data_ptr<T>();
  T* gc = g.colors.data_ptr<T>();
  T* go = g.opacities.data_ptr<T>();
  const T* bg = in.background.data_ptr<T>();
  const T* m = in.means.data_ptr<T>();
  const T* s = in.scales.data_ptr<T>();
  const T* q = in.rotations.data_ptr<T>();
  std::vector<T> scratch_max(N, T(0));
  for (int64_t view = 0; view < V; ++view) {
    const ViewSetup<T> vs = setup_view<T>(in, view);
    const PixelState<T> ps = forward_view<T>(in, vs, view, nullptr, scratch_max.data());
    // Upstream gradient per pixel and channel (r, g, b, depth, alpha).
    std::vector<T> G(HW * kChannels);
    render::cpu::interleave_grad(g_rgb, view, 3, HW, kChannels, 0, G);
    render::cpu::interleave_grad(g_depth, view, 1, HW, kChannels, 3, G);
    render::cpu::interleave_grad(g_alpha, view, 1, HW, kChannels, 4, G);
    render::cpu::BackToFront<T> replay(ps.t_final, kChannels);
    for (int64_t r = (int64_t)vs.gaussians.size() - 1; r >= 0; --r) {
      const ScreenGaussian<T>& sg = vs.gaussians[r];
      const PixelBox& b = vs.boxes[r];
      ScreenGrad<T> gr{};
      for (int y = b.y0; y < b.y1; ++y)
        for (int x = b.x0; x < b.x1; ++x) {
          const int64_t p = (int64_t)y * W + x;
          if (r >= ps.last[p]) continue;
          Fragment<T> f;
          if (!shade(sg, T(x) + T(0.5), T(y) + T(0.5), k, f)) continue;
          const T Tp = replay.step(p, f.alpha);  // transmittance in front of this Gaussian
          const T w = f.alpha * Tp;
          const T fv[kChannels] = {sg.color[0], sg.color[1], sg.color[2], sg.z, T(1)};
          const T* Gp = &G[p * kChannels];
          const T g_a = replay.alpha_grad(p, fv, Gp, f.alpha, Tp, bg);
          for (int c = 0; c < 3; ++c) gr.color[c] += w * Gp[c];
          gr.z += w * Gp[3];
          shade_backward(sg, f, k, g_a, gr);
        }
      // Chain this view's screen-space gradient to the inputs.
      const int64_t n = vs.ids[r];
      for (int c = 0; c < 3; ++c) gc[3 * n + c] += gr.color[c];
      go[n] += gr.opacity;
      preprocess_backward(m + 3 * n, s + 3 * n, q + 4 * n, vs.cam, (int)W, (int)H, gr, gm + 3 * n, gs + 3 * n,
                          gq + 4 * n);
    }
  }
  return g;
}

}  // namespace

GaussianOutputs forward(const GaussianInputs& in) {
  if (in.means.scalar_type() == at::kDouble) return forward_impl<double>(in);
  FLAT_CHECK(in.means.scalar_type() == at::kFloat, "rasterize_gaussians (cpu): expected float32 or float64 tensors");
  return forward_impl<float>(in);
}

GaussianGrads backward(const GaussianInputs& in, const at::Tensor& grad_rgb, const at::Tensor& grad_alpha,
                       const at::Tensor& grad_depth) {
  if (in.means.scalar_type() == at::kDouble) return backward_impl<double>(in, grad_rgb, grad_alpha, grad_depth);
  return backward_impl<float>(in, grad_rgb, grad_alpha, grad_depth);
}

}  // namespace flat::gaussians::cpu
