// Per-surfel and per-pixel maths of the 2D Gaussian surfel rasterizer, shared
// by the CPU reference (templated on float/double) and the CUDA kernels
// (float). Plain C++ with __host__ __device__ under nvcc (FLAT_HD, from
// flat/render/shared/compositing.h): no torch, no std containers.
//
// A surfel in camera space: centre c, tangent axes t_u, t_v (the first two
// columns of R(q) turned into the camera), scales s_u, s_v. Its points are
//     X(u, v) = c + u s_u t_u + v s_v t_v,
// and with K the pixel intrinsics the homogeneous pixel of (u, v, 1) is
//     (x z, y z, z) = M (u, v, 1),   M = K [s_u t_u | s_v t_v | c]
// (2DGS' splat-to-screen transform; its third row gives the camera z). A
// pixel (x, y) sees the (u, v) where M (u, v, 1) is parallel to (x, y, 1):
// with rows m0, m1, m2 of M, (u, v, 1) is parallel to
//     p = (m0 - x m2) x (m1 - y m2),   u = p0 / p2, v = p1 / p2
// (the exact ray-plane intersection; no affine approximation).
#pragma once
#include <cmath>
#include <cstdint>

#include "flat/render/shared/compositing.h"    // FLAT_HD, CompositingConstants and its rules, tmin/tmax
#include "flat/render/shared/fast_math.h"      // fast_exp (the falloff per (pixel, splat) pair)
#include "flat/render/shared/view_geometry.h"  // CameraView, PixelRect

namespace flat::surfels {

using render::CameraView;
using render::CompositingConstants;
using render::fast_exp;
using render::tmax;
using render::tmin;
using SurfelRect = render::PixelRect;  // pixels [x0,x1) x [y0,y1)

// 2DGS' screen-space low-pass: rho2d = kLowPass |p - c_px|^2 (pixels).
constexpr double kLowPass = 2.0;
// Largest rho at which a fragment is kept (3.33 sigma): just above 2 ln 255,
// where an opaque surfel's alpha falls below the default alpha_min, so the
// cap changes nothing unless alpha_min is lowered. The support box holds
// rho <= min(2 ln(opacity / alpha_min), this): every fragment that blends
// lies inside it, so the CPU (box) and CUDA (tiles) shade the same ones.
constexpr double kMaxCutoffSq = 11.1;
// The depth distortion's NDC range (2DGS' released code; the header's
// kDistortionNear / kDistortionFar).
constexpr double kNdcNear = 0.2, kNdcFar = 100.0;

// What one pixel needs of one surfel (also the shared-memory record on CUDA:
// 19 floats and the index, 80 bytes, moved with 128-bit loads).
template <class T>
struct alignas(16) PixelSurfel {
  T M[9];       // splat-to-screen transform, row-major (rows m0, m1, m2)
  T cx, cy;     // projected centre M (0, 0, 1), pixels: the low-pass' centre
  T opacity;
  T normal[3];  // camera-space t_w, facing the camera
  T color[3];
  int32_t index;  // the CPU: the surfel's row in the inputs; CUDA: its element (view in the chunk * N + row)
};

// Gradient of the loss with respect to one surfel's PixelSurfel (18 values;
// the CUDA backward sums them in rows of kSurfelGradStride floats).
template <class T>
struct SurfelGrad {
  T M[9];
  T c[2];
  T normal[3];
  T color[3];
  T opacity;
};
constexpr int kSurfelGradSize = 18;

// ---------------------------------------------------------------- rotation
// q (w, x, y, z), any non-zero norm -> unit quaternion qn and R(qn), row-major
// (columns t_u, t_v, t_w).
template <class T>
FLAT_HD void quat_to_rotation(const T* q, T qn[4], T& inv_norm, T R[9]) {
  inv_norm = T(1) / std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  for (int i = 0; i < 4; ++i) qn[i] = q[i] * inv_norm;
  const T w = qn[0], x = qn[1], y = qn[2], z = qn[3];
  R[0] = T(1) - T(2) * (y * y + z * z);
  R[1] = T(2) * (x * y - w * z);
  R[2] = T(2) * (x * z + w * y);
  R[3] = T(2) * (x * y + w * z);
  R[4] = T(1) - T(2) * (x * x + z * z);
  R[5] = T(2) * (y * z - w * x);
  R[6] = T(2) * (x * z - w * y);
  R[7] = T(2) * (y * z + w * x);
  R[8] = T(1) - T(2) * (x * x + y * y);
}

// dL/dR -> dL/dq of the raw quaternion (through the normalisation), added into gq.
template <class T>
FLAT_HD void quat_backward(const T qn[4], T inv_norm, const T g[9], T* gq) {
  const T w = qn[0], x = qn[1], y = qn[2], z = qn[3];
  T gn[4];
  gn[0] = T(2) * (-z * g[1] + y * g[2] + z * g[3] - x * g[5] - y * g[6] + x * g[7]);
  gn[1] = T(2) * (y * g[1] + z * g[2] + y * g[3] - T(2) * x * g[4] - w * g[5] + z * g[6] + w * g[7] - T(2) * x * g[8]);
  gn[2] = T(2) * (-T(2) * y * g[0] + x * g[1] + w * g[2] + x * g[3] + z * g[5] - w * g[6] + z * g[7] - T(2) * y * g[8]);
  gn[3] = T(2) * (-T(2) * z * g[0] - w * g[1] + x * g[2] + w * g[3] - T(2) * z * g[4] + y * g[5] + x * g[6] + y * g[7]);
  // qn = q / |q|: dq = (gn - (gn . qn) qn) / |q|
  const T d = gn[0] * qn[0] + gn[1] * qn[1] + gn[2] * qn[2] + gn[3] * qn[3];
  for (int i = 0; i < 4; ++i) gq[i] += (gn[i] - d * qn[i]) * inv_norm;
}

// ---------------------------------------------------------------- projection
// A surfel's frame in camera space, shared by the preprocessing's forward and
// backward.
template <class T>
struct SurfelFrame {
  T qn[4], inv_norm;  // unit quaternion, 1 / |q|
  T R[9];             // world rotation R(qn), row-major
  T tu[3], tv[3], tw[3];  // camera-space axes
  T c[3];             // camera-space centre
  T flip;             // +1 or -1: flip * tw faces the camera
};

template <class T>
FLAT_HD SurfelFrame<T> surfel_frame(const T* mean, const T* quat, const CameraView<T>& cam) {
  SurfelFrame<T> f;
  quat_to_rotation(quat, f.qn, f.inv_norm, f.R);
  for (int r = 0; r < 3; ++r) {
    f.c[r] = cam.R[3 * r] * mean[0] + cam.R[3 * r + 1] * mean[1] + cam.R[3 * r + 2] * mean[2] + cam.t[r];
    f.tu[r] = cam.R[3 * r] * f.R[0] + cam.R[3 * r + 1] * f.R[3] + cam.R[3 * r + 2] * f.R[6];
    f.tv[r] = cam.R[3 * r] * f.R[1] + cam.R[3 * r + 1] * f.R[4] + cam.R[3 * r + 2] * f.R[7];
    f.tw[r] = cam.R[3 * r] * f.R[2] + cam.R[3 * r + 1] * f.R[5] + cam.R[3 * r + 2] * f.R[8];
  }
  // Facing the camera: the normal points against the ray to the centre (2DGS).
  f.flip = f.tw[0] * f.c[0] + f.tw[1] * f.c[1] + f.tw[2] * f.c[2] > T(0) ? T(-1) : T(1);
  return f;
}

// M = K [s_u t_u | s_v t_v | c], K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]].
template <class T>
FLAT_HD void splat_to_screen(const SurfelFrame<T>& f, const T* scale, const CameraView<T>& cam, T M[9]) {
  T A[9];  // rows of [s_u t_u | s_v t_v | c]
  for (int r = 0; r < 3; ++r) {
    A[3 * r] = scale[0] * f.tu[r];
    A[3 * r + 1] = scale[1] * f.tv[r];
    A[3 * r + 2] = f.c[r];
  }
  for (int c = 0; c < 3; ++c) {
    M[c] = cam.fx * A[c] + cam.cx * A[6 + c];
    M[3 + c] = cam.fy * A[3 + c] + cam.cy * A[6 + c];
    M[6 + c] = A[6 + c];
  }
}

// The squared cutoff radius (in sigmas) beyond which no fragment of a surfel
// of this opacity reaches alpha_min (rho > 2 ln(opacity / alpha_min) gives
// alpha < alpha_min); <= 0: it never does.
template <class T>
FLAT_HD T cutoff_sq(T opacity, const CompositingConstants& k) {
  if (!(opacity > T(0))) return T(-1);
  if (!(k.alpha_min > 0.f)) return T(kMaxCutoffSq);
  return tmin(T(kMaxCutoffSq), T(2) * std::log(opacity / T(k.alpha_min)));
}

// The pixel box holding every pixel centre where rho <= r2: the tight box of
// the projected ellipse u^2 + v^2 = r2 (its dual conic M diag(r2, r2, -1) M^T,
// whose tangents x = a solve C00 - 2 a C02 + a^2 C22 = 0), joined with the
// low-pass disc kLowPass |p - c_px|^2 <= r2. When the ellipse reaches the
// camera's plane (C22 >= 0) its image is unbounded: the whole image.
// Returns false when the box holds no pixel.
template <class T>
FLAT_HD bool surfel_rect(const T M[9], T cx, T cy, T r2, int width, int height, SurfelRect& rect) {
  // A little larger than exact, against rounding (the per-pixel alpha_min test decides).
  const T r2b = r2 * T(1.001);
  const T* m0 = M;
  const T* m1 = M + 3;
  const T* m2 = M + 6;
  auto dual = [&](const T* a, const T* b) { return r2b * (a[0] * b[0] + a[1] * b[1]) - a[2] * b[2]; };
  const T rad = std::sqrt(r2b / T(kLowPass)) + T(1e-3);
  T lo[2] = {cx - rad, cy - rad}, hi[2] = {cx + rad, cy + rad};
  const T c22 = dual(m2, m2);
  if (c22 < T(0)) {
    const T mid[2] = {dual(m0, m2) / c22, dual(m1, m2) / c22};
    const T diag[2] = {dual(m0, m0) / c22, dual(m1, m1) / c22};
    for (int d = 0; d < 2; ++d) {
      const T half = std::sqrt(tmax(mid[d] * mid[d] - diag[d], T(0))) + T(1e-3);
      lo[d] = tmin(lo[d], mid[d] - half);
      hi[d] = tmax(hi[d], mid[d] + half);
    }
  } else {
    lo[0] = lo[1] = T(-1e30);
    hi[0] = hi[1] = T(1e30);
  }
  return render::covered_pixels(lo, hi, width, height, rect);
}

// The centre's camera z for the depth sort key, every product and sum
// rounded on its own: nvcc fuses a * b + c into one FMA (one rounding), the
// host compiler (x86-64, no -mfma) does not, and a key one step apart
// reorders two surfels at near-equal depth, which changes whole regions of
// pixels between the CUDA kernels and the float CPU reference. Rounded alike,
// both sort the same keys. (Culling and the screen data keep f.c[2].)
FLAT_HD float mul_rn(float a, float b) {
#if defined(__CUDA_ARCH__)
  return __fmul_rn(a, b);
#else
  return a * b;
#endif
}
FLAT_HD float add_rn(float a, float b) {
#if defined(__CUDA_ARCH__)
  return __fadd_rn(a, b);
#else
  return a + b;
#endif
}
FLAT_HD double mul_rn(double a, double b) { return a * b; }
FLAT_HD double add_rn(double a, double b) { return a + b; }
template <class T>
FLAT_HD T centre_depth(const T* mean, const CameraView<T>& cam) {
  return add_rn(add_rn(add_rn(mul_rn(cam.R[6], mean[0]), mul_rn(cam.R[7], mean[1])), mul_rn(cam.R[8], mean[2])),
                cam.t[2]);
}

// Forward of the per-(view, surfel) preprocessing. Returns false when the
// surfel is culled (centre nearer than near_plane, or no pixel can reach
// alpha_min); fills the geometry of `out` (not colour, opacity, index), the
// support box and the depth sort key (camera z of the centre, centre_depth()).
template <class T>
FLAT_HD bool preprocess_forward(const T* mean, const T* scale, const T* quat, T opacity, const CameraView<T>& cam,
                                const CompositingConstants& k, int width, int height, PixelSurfel<T>& out,
                                SurfelRect& rect, T& key) {
  const SurfelFrame<T> f = surfel_frame(mean, quat, cam);
  if (!(f.c[2] >= T(k.near_plane))) return false;  // behind or too near (also NaN)
  const T r2 = cutoff_sq(opacity, k);
  if (!(r2 > T(0))) return false;
  splat_to_screen(f, scale, cam, out.M);
  out.cx = out.M[2] / out.M[8];
  out.cy = out.M[5] / out.M[8];
  for (int r = 0; r < 3; ++r) out.normal[r] = f.flip * f.tw[r];
  key = tmax(centre_depth(mean, cam), T(0));  // >= 0: depth_sort_key() keeps no sign bit
  return surfel_rect(out.M, out.cx, out.cy, r2, width, height, rect);
}

// Reverse of preprocess_forward's geometry: gradient of the PixelSurfel
// geometry (g.M, g.c, g.normal) -> gradients of the mean, scales and raw
// quaternion, added into gmean[3], gscale[2], gquat[4].
template <class T>
FLAT_HD void preprocess_backward(const T* mean, const T* scale, const T* quat, const CameraView<T>& cam,
                                 const SurfelGrad<T>& g, T* gmean, T* gscale, T* gquat) {
  const SurfelFrame<T> f = surfel_frame(mean, quat, cam);
  T M[9];
  splat_to_screen(f, scale, cam, M);
  T gM[9];
  for (int i = 0; i < 9; ++i) gM[i] = g.M[i];
  // c_px = (M02 / M22, M12 / M22)
  const T inv_z = T(1) / M[8];
  gM[2] += g.c[0] * inv_z;
  gM[5] += g.c[1] * inv_z;
  gM[8] -= (g.c[0] * M[2] + g.c[1] * M[5]) * inv_z * inv_z;
  // M = K A: rows m0 = fx a0 + cx a2, m1 = fy a1 + cy a2, m2 = a2
  T gA[9];
  for (int c = 0; c < 3; ++c) {
    gA[c] = cam.fx * gM[c];
    gA[3 + c] = cam.fy * gM[3 + c];
    gA[6 + c] = cam.cx * gM[c] + cam.cy * gM[3 + c] + gM[6 + c];
  }
  // A = [s_u t_u | s_v t_v | c]
  T gtu[3], gtv[3], gtw[3], gc[3];
  for (int r = 0; r < 3; ++r) {
    gtu[r] = scale[0] * gA[3 * r];
    gtv[r] = scale[1] * gA[3 * r + 1];
    gc[r] = gA[3 * r + 2];
    gtw[r] = f.flip * g.normal[r];
  }
  gscale[0] += gA[0] * f.tu[0] + gA[3] * f.tu[1] + gA[6] * f.tu[2];
  gscale[1] += gA[1] * f.tv[0] + gA[4] * f.tv[1] + gA[7] * f.tv[2];
  // Camera space -> world: the transpose of the camera rotation.
  T gR[9];
  for (int col = 0; col < 3; ++col) {
    gmean[col] += cam.R[col] * gc[0] + cam.R[3 + col] * gc[1] + cam.R[6 + col] * gc[2];
    gR[3 * col] = cam.R[col] * gtu[0] + cam.R[3 + col] * gtu[1] + cam.R[6 + col] * gtu[2];
    gR[3 * col + 1] = cam.R[col] * gtv[0] + cam.R[3 + col] * gtv[1] + cam.R[6 + col] * gtv[2];
    gR[3 * col + 2] = cam.R[col] * gtw[0] + cam.R[3 + col] * gtw[1] + cam.R[6 + col] * gtw[2];
  }
  quat_backward(f.qn, f.inv_norm, gR, gquat);
}

// ---------------------------------------------------------------- fragment

// Everything one pixel computes of one surfel; reused by the backward.
template <class T>
struct SurfelFragment {
  T u, v;      // local coordinates of the ray-plane intersection (sigmas)
  T G;         // exp(-rho / 2)
  T alpha;     // min(alpha_max, opacity G)
  T z;         // camera z of the intersection, or of the centre where the low-pass wins
  bool lowpass;  // rho = rho2d (u, v then unused)
};

// Fragment of surfel s at pixel centre (px, py). Returns whether it blends:
// alpha >= alpha_min (and > 0), rho <= kMaxCutoffSq and z >= near_plane (a
// ray meeting the plane behind or too near the camera sees nothing).
template <class T>
FLAT_HD bool shade(const PixelSurfel<T>& s, T px, T py, const CompositingConstants& k, SurfelFragment<T>& f) {
  const T* M = s.M;
  const T kx[3] = {M[0] - px * M[6], M[1] - px * M[7], M[2] - px * M[8]};
  const T ly[3] = {M[3] - py * M[6], M[4] - py * M[7], M[5] - py * M[8]};
  const T p0 = kx[1] * ly[2] - kx[2] * ly[1];
  const T p1 = kx[2] * ly[0] - kx[0] * ly[2];
  const T p2 = kx[0] * ly[1] - kx[1] * ly[0];
  f.u = p0 / p2;
  f.v = p1 / p2;
  const T rho3d = f.u * f.u + f.v * f.v;
  const T dx = px - s.cx, dy = py - s.cy;
  const T rho2d = T(kLowPass) * (dx * dx + dy * dy);
  // The low-pass wins also where the ray misses the plane (p2 = 0: NaN or inf).
  f.lowpass = !(rho3d <= rho2d);
  const T rho = f.lowpass ? rho2d : rho3d;
  f.z = f.lowpass ? M[8] : f.u * M[6] + f.v * M[7] + M[8];
  f.G = fast_exp(T(-0.5) * rho);
  f.alpha = render::fragment_alpha(s.opacity, f.G, k);
  return render::fragment_blends(f.alpha, k) && rho <= T(kMaxCutoffSq) && f.z >= T(k.near_plane);
}

// dL/dalpha and dL/dz of fragment f (from shade() at (px, py)) -> gradients
// of s's M, c_px and opacity, added into g.
template <class T>
FLAT_HD void fragment_backward(const PixelSurfel<T>& s, T px, T py, const SurfelFragment<T>& f, T g_alpha, T g_z,
                               const CompositingConstants& k, SurfelGrad<T>& g) {
  T g_rho = T(0);
  if (render::below_alpha_cap(s.opacity, f.G, k)) {
    g.opacity += g_alpha * f.G;
    g_rho = T(-0.5) * g_alpha * s.opacity * f.G;
  }
  if (f.lowpass) {  // rho = kLowPass |p - c|^2, z = M22
    const T s2 = T(2 * kLowPass) * g_rho;
    g.c[0] -= s2 * (px - s.cx);
    g.c[1] -= s2 * (py - s.cy);
    g.M[8] += g_z;
    return;
  }
  const T* M = s.M;
  // rho = u^2 + v^2, z = u M20 + v M21 + M22
  const T gu = T(2) * f.u * g_rho + g_z * M[6];
  const T gv = T(2) * f.v * g_rho + g_z * M[7];
  g.M[6] += g_z * f.u;
  g.M[7] += g_z * f.v;
  g.M[8] += g_z;
  // u = p0 / p2, v = p1 / p2, p = kx x ly
  const T kx[3] = {M[0] - px * M[6], M[1] - px * M[7], M[2] - px * M[8]};
  const T ly[3] = {M[3] - py * M[6], M[4] - py * M[7], M[5] - py * M[8]};
  const T p2 = kx[0] * ly[1] - kx[1] * ly[0];
  const T gp[3] = {gu / p2, gv / p2, -(gu * f.u + gv * f.v) / p2};
  // dL/dkx = ly x gp, dL/dly = gp x kx
  const T gk[3] = {ly[1] * gp[2] - ly[2] * gp[1], ly[2] * gp[0] - ly[0] * gp[2], ly[0] * gp[1] - ly[1] * gp[0]};
  const T gl[3] = {gp[1] * kx[2] - gp[2] * kx[1], gp[2] * kx[0] - gp[0] * kx[2], gp[0] * kx[1] - gp[1] * kx[0]};
  for (int c = 0; c < 3; ++c) {
    g.M[c] += gk[c];
    g.M[3 + c] += gl[c];
    g.M[6 + c] -= px * gk[c] + py * gl[c];
  }
}

// ---------------------------------------------------------------- distortion
// 2DGS' NDC depth m(z) = far (z - near) / ((far - near) z) and dm/dz.
template <class T>
FLAT_HD T ndc_depth(T z) {
  return T(kNdcFar / (kNdcFar - kNdcNear)) * (T(1) - T(kNdcNear) / z);
}
template <class T>
FLAT_HD T ndc_depth_grad(T z) {
  return T(kNdcFar * kNdcNear / (kNdcFar - kNdcNear)) / (z * z);
}

}  // namespace flat::surfels
