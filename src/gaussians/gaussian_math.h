// Per-Gaussian and per-pixel maths of the 3D Gaussian splatting rasterizer,
// shared by the CPU reference (templated on float/double) and the CUDA
// kernels (float). Plain C++ with __host__ __device__ under nvcc (FLAT_HD of
// flat/render/shared/compositing.h): no torch, no std containers. docs/rasterizer_3dgs.md
// has the equations.
//
// Per (view, Gaussian): camera-space mean t = W m + tw; Sigma = M M^T with
// M = R(q / |q|) diag(s); EWA: cov = J W Sigma W^T J^T + 0.3 I (pixels^2),
// J the projection's Jacobian at t with t.x/t.z, t.y/t.z clamped to 1.3x the
// image's half-extent about the principal point (3DGS; gsplat for an
// off-centre principal point); conic = cov^-1. Per pixel centre p,
// d = p - mean2d, q = d^T conic d: alpha = min(alpha_max, o exp(-q/2)) where
// q <= 9 (3 sigma), else 0.
#pragma once
#include <cmath>
#include <cstdint>

#include "flat/render/shared/compositing.h"    // FLAT_HD, CompositingConstants and its rules, tmin/tmax
#include "flat/render/shared/fast_math.h"      // fast_exp (the falloff per (pixel, splat) pair)
#include "flat/render/shared/view_geometry.h"  // CameraView, make_camera_view, PixelRect

namespace flat::gaussians {

using render::CameraView;
using render::CompositingConstants;
using render::fast_exp;
using render::make_camera_view;
using render::tmax;
using render::tmin;

constexpr double kDilation = 0.3;     // pixels^2 added to the 2-D covariance's diagonal (3DGS)
constexpr double kClampFactor = 1.3;  // J's screen position clamped to 1.3x the half-extent (3DGS)
constexpr double kSupportSq = 9.0;    // support: q = d^T conic d <= 3^2

// What one pixel needs of one Gaussian in one view (also the shared-memory
// record on CUDA: 12 floats, three 16-byte loads).
template <class T>
struct alignas(16) ScreenGaussian {
  T mx, my;    // projected mean (pixels, pixel-centre convention)
  T conic[3];  // inverse 2-D covariance: a, b, c of [[a, b], [b, c]]
  T opacity;
  T color[3];
  T z;        // camera depth of the mean (the depth output's value)
  T extent2;  // the support's bound e2 on q (below): no kept fragment has q > extent2
  T pad;
};

// Pixels [x0,x1) x [y0,y1) whose centres may reach alpha_min (and q <= 9).
using PixelBox = render::PixelRect;

// Gradient of the loss with respect to one Gaussian's ScreenGaussian in one
// view. conic[1] is dL/db with b the matrix's off-diagonal entry taken once
// as a symmetric pair (q = a dx^2 + 2 b dx dy + c dy^2 gives dq/db = 2 dx dy).
template <class T>
struct ScreenGrad {
  T mean2d[2];
  T conic[3];
  T opacity;
  T color[3];
  T z;
};
constexpr int kScreenGradSize = 10;  // number of T in ScreenGrad


// ---------------------------------------------------------------- 3-D covariance
// Rotation of a unit quaternion (w, x, y, z), row-major.
template <class T>
FLAT_HD void quat_to_rotation(const T q[4], T R[9]) {
  const T w = q[0], x = q[1], y = q[2], z = q[3];
  R[0] = T(1) - T(2) * (y * y + z * z), R[1] = T(2) * (x * y - w * z), R[2] = T(2) * (x * z + w * y);
  R[3] = T(2) * (x * y + w * z), R[4] = T(1) - T(2) * (x * x + z * z), R[5] = T(2) * (y * z - w * x);
  R[6] = T(2) * (x * z - w * y), R[7] = T(2) * (y * z + w * x), R[8] = T(1) - T(2) * (x * x + y * y);
}

// Reverse of quat_to_rotation: gR (row-major) -> gradient of the unit quaternion.
template <class T>
FLAT_HD void quat_to_rotation_backward(const T q[4], const T g[9], T gq[4]) {
  const T w = q[0], x = q[1], y = q[2], z = q[3];
  gq[0] = T(2) * (-z * g[1] + y * g[2] + z * g[3] - x * g[5] - y * g[6] + x * g[7]);
  gq[1] = T(2) * (y * g[1] + z * g[2] + y * g[3] - T(2) * x * g[4] - w * g[5] + z * g[6] + w * g[7] - T(2) * x * g[8]);
  gq[2] = T(2) * (-T(2) * y * g[0] + x * g[1] + w * g[2] + x * g[3] + z * g[5] - w * g[6] + z * g[7] - T(2) * y * g[8]);
  gq[3] = T(2) * (-T(2) * z * g[0] - w * g[1] + x * g[2] + w * g[3] - T(2) * z * g[4] + y * g[5] + x * g[6] + y * g[7]);
}

// M = R(q / |q|) diag(s), row-major; qn gets the unit quaternion, returns |q|.
template <class T>
FLAT_HD T scaled_rotation(const T* scale, const T* quat, T qn[4], T M[9]) {
  const T norm = std::sqrt(quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2] + quat[3] * quat[3]);
  for (int i = 0; i < 4; ++i) qn[i] = quat[i] / norm;
  T R[9];
  quat_to_rotation(qn, R);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) M[3 * r + c] = R[3 * r + c] * scale[c];
  return norm;
}

// ---------------------------------------------------------------- projection
// Everything the projection's forward and backward share, recomputed by both.
template <class T>
struct Projection {
  T t[3];               // camera-space mean
  T qn[4];              // unit quaternion
  T qnorm;              // |q|
  T M[9];               // R diag(s)
  T u, v;               // t.x / t.z and t.y / t.z, clamped (J's screen position)
  bool free_u, free_v;  // false where the clamp is active (no gradient to t.x / t.y through J)
  T P[6];               // J W (2x3, row-major): cov = P Sigma P^T + 0.3 I
  T Sigma[9];           // world-space 3-D covariance
  T cov[3];             // 2-D covariance a, b, c (dilated)
};

// The image's clamp of J's screen position, as ratios x/z: [-lo, hi].
template <class T>
FLAT_HD void clamp_limits(const CameraView<T>& cam, int width, int height, T& lo_x, T& hi_x, T& lo_y, T& hi_y) {
  const T margin = T(kClampFactor - 1.0);  // beyond the image edge, in half-extents
  const T half_x = T(0.5) * T(width) / cam.fx, half_y = T(0.5) * T(height) / cam.fy;
  lo_x = cam.cx / cam.fx + margin * half_x;
  hi_x = (T(width) - cam.cx) / cam.fx + margin * half_x;
  lo_y = cam.cy / cam.fy + margin * half_y;
  hi_y = (T(height) - cam.cy) / cam.fy + margin * half_y;
}

// The projection's intermediates (no culling; t[2] must be > 0).
template <class T>
FLAT_HD void project(const T* mean, const T* scale, const T* quat, const CameraView<T>& cam, int width, int height,
                     Projection<T>& pr) {
  for (int r = 0; r < 3; ++r)
    pr.t[r] = cam.R[3 * r] * mean[0] + cam.R[3 * r + 1] * mean[1] + cam.R[3 * r + 2] * mean[2] + cam.t[r];
  pr.qnorm = scaled_rotation(scale, quat, pr.qn, pr.M);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      pr.Sigma[3 * r + c] =
          pr.M[3 * r] * pr.M[3 * c] + pr.M[3 * r + 1] * pr.M[3 * c + 1] + pr.M[3 * r + 2] * pr.M[3 * c + 2];
  T lo_x, hi_x, lo_y, hi_y;
  clamp_limits(cam, width, height, lo_x, hi_x, lo_y, hi_y);
  const T z = pr.t[2];
  const T ux = pr.t[0] / z, vy = pr.t[1] / z;
  pr.free_u = ux >= -lo_x && ux <= hi_x;
  pr.free_v = vy >= -lo_y && vy <= hi_y;
  pr.u = tmin(tmax(ux, -lo_x), hi_x);
  pr.v = tmin(tmax(vy, -lo_y), hi_y);
  // J = [[fx/z, 0, -fx u/z], [0, fy/z, -fy v/z]]; P = J W (W: rows of cam.R).
  const T j00 = cam.fx / z, j02 = -cam.fx * pr.u / z, j11 = cam.fy / z, j12 = -cam.fy * pr.v / z;
  for (int c = 0; c < 3; ++c) {
    pr.P[c] = j00 * cam.R[c] + j02 * cam.R[6 + c];
    pr.P[3 + c] = j11 * cam.R[3 + c] + j12 * cam.R[6 + c];
  }
  // cov = P Sigma P^T + 0.3 I
  T PS[6];
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 3; ++c)
      PS[3 * r + c] = pr.P[3 * r] * pr.Sigma[c] + pr.P[3 * r + 1] * pr.Sigma[3 + c] + pr.P[3 * r + 2] * pr.Sigma[6 + c];
  pr.cov[0] = PS[0] * pr.P[0] + PS[1] * pr.P[1] + PS[2] * pr.P[2] + T(kDilation);
  pr.cov[1] = PS[0] * pr.P[3] + PS[1] * pr.P[4] + PS[2] * pr.P[5];
  pr.cov[2] = PS[3] * pr.P[3] + PS[4] * pr.P[4] + PS[5] * pr.P[5] + T(kDilation);
}

// Forward of the per-(view, Gaussian) preprocessing. Returns false when the
// Gaussian is culled (mean nearer than near_plane or NaN, opacity below
// alpha_min, degenerate 2-D covariance, support off the image); fills the
// geometry of `out` (mean, conic, z; not colour/opacity) and the pixel box.
template <class T>
FLAT_HD bool preprocess_forward(const T* mean, const T* scale, const T* quat, T opacity, const CameraView<T>& cam,
                                const CompositingConstants& k, int width, int height, ScreenGaussian<T>& out,
                                PixelBox& box) {
  if (!render::opacity_can_blend(opacity, k)) return false;
  T tz = cam.R[6] * mean[0] + cam.R[7] * mean[1] + cam.R[8] * mean[2] + cam.t[2];
  if (!(tz >= T(k.near_plane))) return false;  // behind the near plane (also NaN)
  Projection<T> pr;
  project(mean, scale, quat, cam, width, height, pr);
  const T det = pr.cov[0] * pr.cov[2] - pr.cov[1] * pr.cov[1];
  if (!(det > T(0))) return false;
  out.conic[0] = pr.cov[2] / det;
  out.conic[1] = -pr.cov[1] / det;
  out.conic[2] = pr.cov[0] / det;
  out.mx = cam.fx * pr.t[0] / pr.t[2] + cam.cx;
  out.my = cam.fy * pr.t[1] / pr.t[2] + cam.cy;
  out.z = pr.t[2];
  // Support: q <= min(9, 2 log(o / alpha_min)) (beyond it alpha < alpha_min);
  // the ellipse q <= e2 spans +-sqrt(e2 cov_xx) in x, +-sqrt(e2 cov_yy) in y.
  // 0.1% wider, so that rounding at the edge is decided by the per-pixel test alone.
  T e2 = T(kSupportSq);
  if (k.alpha_min > 0.f) e2 = tmin(e2, T(2) * std::log(opacity / T(k.alpha_min)));
  e2 *= T(1.001);
  out.extent2 = e2;
  const T hx = std::sqrt(e2 * pr.cov[0]), hy = std::sqrt(e2 * pr.cov[2]);
  const T lo[2] = {out.mx - hx, out.my - hy}, hi[2] = {out.mx + hx, out.my + hy};
  return render::covered_pixels(lo, hi, width, height, box);
}

// Reverse of preprocess_forward's geometry for one view: g (mean2d, conic, z)
// -> gradients of the mean, scales and raw quaternion, added into gm[3],
// gs[3], gq[4]. Recomputes the forward intermediates.
template <class T>
FLAT_HD void preprocess_backward(const T* mean, const T* scale, const T* quat, const CameraView<T>& cam, int width,
                                 int height, const ScreenGrad<T>& g, T* gm, T* gs, T* gq) {
  Projection<T> pr;
  project(mean, scale, quat, cam, width, height, pr);
  const T z = pr.t[2];
  const T det = pr.cov[0] * pr.cov[2] - pr.cov[1] * pr.cov[1];
  const T Q[3] = {pr.cov[2] / det, -pr.cov[1] / det, pr.cov[0] / det};
  // conic = cov^-1: dL/dcov = -Q G Q (G symmetric: off-diagonal dL/db / 2 each side)
  const T G00 = g.conic[0], G01 = T(0.5) * g.conic[1], G11 = g.conic[2];
  const T QG00 = Q[0] * G00 + Q[1] * G01, QG01 = Q[0] * G01 + Q[1] * G11;
  const T QG10 = Q[1] * G00 + Q[2] * G01, QG11 = Q[1] * G01 + Q[2] * G11;
  // Full symmetric matrix gradient of cov (C01 = C10).
  const T C00 = -(QG00 * Q[0] + QG01 * Q[1]);
  const T C01 = -(QG00 * Q[1] + QG01 * Q[2]);
  const T C11 = -(QG10 * Q[1] + QG11 * Q[2]);
  const T C[4] = {C00, C01, C01, C11};
  // cov = P Sigma P^T: gP = 2 C P Sigma, gSigma = P^T C P
  T PS[6];
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 3; ++c)
      PS[3 * r + c] = pr.P[3 * r] * pr.Sigma[c] + pr.P[3 * r + 1] * pr.Sigma[3 + c] + pr.P[3 * r + 2] * pr.Sigma[6 + c];
  T gP[6];
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 3; ++c) gP[3 * r + c] = T(2) * (C[2 * r] * PS[c] + C[2 * r + 1] * PS[3 + c]);
  T CP[6];
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 3; ++c) CP[3 * r + c] = C[2 * r] * pr.P[c] + C[2 * r + 1] * pr.P[3 + c];
  T gSigma[9];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) gSigma[3 * r + c] = pr.P[r] * CP[c] + pr.P[3 + r] * CP[3 + c];
  // Sigma = M M^T: gM = (gSigma + gSigma^T) M
  T gM[9];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      T acc = T(0);
      for (int k = 0; k < 3; ++k) acc += (gSigma[3 * r + k] + gSigma[3 * k + r]) * pr.M[3 * k + c];
      gM[3 * r + c] = acc;
    }
  // M = R diag(s): gR_rc = gM_rc s_c, gs_c = sum_r gM_rc R_rc (R_rc = M_rc / s_c, recomputed)
  T R[9], gR[9];
  quat_to_rotation(pr.qn, R);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) gR[3 * r + c] = gM[3 * r + c] * scale[c];
  for (int c = 0; c < 3; ++c) gs[c] += gM[c] * R[c] + gM[3 + c] * R[3 + c] + gM[6 + c] * R[6 + c];
  T gqn[4];
  quat_to_rotation_backward(pr.qn, gR, gqn);
  // qn = q / |q|: gq = (gqn - qn (qn . gqn)) / |q|
  const T dot = gqn[0] * pr.qn[0] + gqn[1] * pr.qn[1] + gqn[2] * pr.qn[2] + gqn[3] * pr.qn[3];
  for (int i = 0; i < 4; ++i) gq[i] += (gqn[i] - pr.qn[i] * dot) / pr.qnorm;
  // P = J W: gJ = gP W^T (only J's non-zero entries j00, j02, j11, j12)
  const T gj00 = gP[0] * cam.R[0] + gP[1] * cam.R[1] + gP[2] * cam.R[2];
  const T gj02 = gP[0] * cam.R[6] + gP[1] * cam.R[7] + gP[2] * cam.R[8];
  const T gj11 = gP[3] * cam.R[3] + gP[4] * cam.R[4] + gP[5] * cam.R[5];
  const T gj12 = gP[3] * cam.R[6] + gP[4] * cam.R[7] + gP[5] * cam.R[8];
  // j00 = fx/z, j02 = -fx u/z, j11 = fy/z, j12 = -fy v/z; u = x/z unless clamped
  T gt[3] = {T(0), T(0), g.z};
  gt[2] += -(gj00 * cam.fx + gj11 * cam.fy) / (z * z) + (gj02 * cam.fx * pr.u + gj12 * cam.fy * pr.v) / (z * z);
  const T gu = -gj02 * cam.fx / z, gv = -gj12 * cam.fy / z;
  if (pr.free_u) gt[0] += gu / z, gt[2] -= gu * pr.u / z;
  if (pr.free_v) gt[1] += gv / z, gt[2] -= gv * pr.v / z;
  // mean2d = (fx x/z + cx, fy y/z + cy)
  gt[0] += g.mean2d[0] * cam.fx / z;
  gt[1] += g.mean2d[1] * cam.fy / z;
  gt[2] -= (g.mean2d[0] * cam.fx * pr.t[0] + g.mean2d[1] * cam.fy * pr.t[1]) / (z * z);
  // t = W m + tw -> gm = W^T gt
  for (int c = 0; c < 3; ++c) gm[c] += cam.R[c] * gt[0] + cam.R[3 + c] * gt[1] + cam.R[6 + c] * gt[2];
}

// ---------------------------------------------------------------- tiles
// d^T conic d.
template <class T>
FLAT_HD T quad_form(const ScreenGaussian<T>& g, T dx, T dy) {
  return g.conic[0] * dx * dx + T(2) * g.conic[1] * dx * dy + g.conic[2] * dy * dy;
}

// Smallest q = d^T conic d over the rectangle of points [x0, x1] x [y0, y1]
// (x0 <= x1, y0 <= y1; pixel units): 0 when it holds the mean, else the
// smallest over its four edges (conic is positive definite), each a 1-D
// quadratic minimised in closed form and clamped to the edge. The CUDA
// binning skips a tile whose pixel centres all have q > extent2.
template <class T>
FLAT_HD T min_q_over_rect(const ScreenGaussian<T>& g, T x0, T x1, T y0, T y1) {
  const T lx = x0 - g.mx, hx = x1 - g.mx, ly = y0 - g.my, hy = y1 - g.my;
  if (lx <= T(0) && hx >= T(0) && ly <= T(0) && hy >= T(0)) return T(0);
  const T a = g.conic[0], b = g.conic[1], c = g.conic[2];
  T best = T(1e30);
  for (int side = 0; side < 2; ++side) {
    const T dx = side ? hx : lx;  // vertical edge: q minimal at dy = -b dx / c
    best = tmin(best, quad_form(g, dx, tmin(tmax(-b * dx / c, ly), hy)));
    const T dy = side ? hy : ly;  // horizontal edge: at dx = -b dy / a
    best = tmin(best, quad_form(g, tmin(tmax(-b * dy / a, lx), hx), dy));
  }
  return best;
}

// ---------------------------------------------------------------- fragment
// What one pixel computes of one Gaussian; reused by the backward.
template <class T>
struct Fragment {
  T dx, dy;  // pixel centre - projected mean
  T G;       // exp(-q/2), 0 outside the 3-sigma support
  T alpha;   // min(alpha_max, opacity G)
};

// px, py: pixel centre. Returns false when the fragment is skipped (outside
// the support or alpha < alpha_min); the CPU and CUDA passes call exactly this.
template <class T>
FLAT_HD bool shade(const ScreenGaussian<T>& g, T px, T py, const CompositingConstants& k, Fragment<T>& f) {
  f.dx = px - g.mx;
  f.dy = py - g.my;
  const T q = quad_form(g, f.dx, f.dy);
  if (!(q <= T(kSupportSq))) return false;
  f.G = fast_exp(T(-0.5) * q);
  f.alpha = render::fragment_alpha(g.opacity, f.G, k);
  return render::fragment_blends(f.alpha, k);
}

// d alpha -> the Gaussian's opacity, conic and mean2d gradients (added into
// gr), given a fragment f of g that shade() kept. At the cap alpha is flat.
template <class T>
FLAT_HD void shade_backward(const ScreenGaussian<T>& g, const Fragment<T>& f, const CompositingConstants& k, T g_alpha,
                            ScreenGrad<T>& gr) {
  if (!render::below_alpha_cap(g.opacity, f.G, k)) return;
  gr.opacity += g_alpha * f.G;
  const T g_q = T(-0.5) * g_alpha * g.opacity * f.G;  // q = a dx^2 + 2 b dx dy + c dy^2
  gr.conic[0] += g_q * f.dx * f.dx;
  gr.conic[1] += g_q * T(2) * f.dx * f.dy;
  gr.conic[2] += g_q * f.dy * f.dy;
  // d = p - mean2d: dq/dmean2d = -2 conic d
  gr.mean2d[0] -= g_q * T(2) * (g.conic[0] * f.dx + g.conic[1] * f.dy);
  gr.mean2d[1] -= g_q * T(2) * (g.conic[1] * f.dx + g.conic[2] * f.dy);
}

}  // namespace flat::gaussians
