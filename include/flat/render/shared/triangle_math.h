// Per-triangle and per-pixel maths of the triangle rasterizer, shared by the
// CPU reference (templated on float/double) and the CUDA kernels (float).
// Plain C++ with __host__ __device__ under nvcc: no torch, no std containers.
// What the three rasterizers share (FLAT_HD, the compositing constants and
// rules, the depth key, the camera view, pixel rectangles) is in
// compositing.h and view_geometry.h beside it; this header is the
// triangle's own maths.
//
// Notation (paper, Method, "Window Function"): projected vertices q_k, edge
// i runs q_i -> q_{i+1}, L_i(p) its signed distance (negative inside), rho the
// inradius, u_i(p) = -L_i(p)/rho (1 at the incenter s). Since u_i is affine in
// p and u_i(s) = 1 for every triangle, we store it as
//     u_i(p) = 1 + n_i . (p - s),   n_i = (P / A2) perp(e_i) / |e_i|
// (P perimeter, A2 twice the signed area, perp(e) = (-e.y, e.x)); |n_i| = 1/rho,
// so the inradius and every vertex receive gradient through n_i and s.
// Depth: the triangle's plane in camera space is h . X = 1, so a pixel ray
// d = ((x-cx)/fx, (y-cy)/fy, 1) meets it at camera depth z = 1 / (h . d).
#pragma once
#include <cmath>
#include <cstdint>

#include "flat/render/shared/compositing.h"
#include "flat/render/shared/fast_math.h"
#include "flat/render/shared/view_geometry.h"

namespace flat::render {

enum WindowKind : int { kWindowFlat = 0, kWindowTS = 1 };

// Constants of one triangle rasterization (docs/rasterizer.md lists each
// one): the compositing ones every primitive has, and the window's and the
// culling's of triangles.
struct RasterConstants : CompositingConstants {
  float eps = 0.1f;            // FLAT window: support beyond each edge, in inradii
  float min_inradius = 1e-3f;  // cull triangles with a screen inradius below this (pixels)
  float min_cos = 1e-3f;       // cull edge-on triangles: |cos(normal, view ray to centroid)| below this
  int window = kWindowFlat;
};

// What one pixel needs of one triangle (also the shared-memory record on CUDA;
// 16-byte aligned so that it moves with 128-bit loads: 23 floats with padding).
// The window's inputs come first: the CUDA coverage pass reads only the first
// three 16-byte groups.
template <class T>
struct alignas(16) PixelTri {
  T sx, sy;          // incenter (pixels)
  T nx[3], ny[3];    // gradient of u_i in pixels
  T opacity, sigma;
  T zlo, zhi;        // vertex depth range: per-pixel depth is clamped into it
  T h[3];            // camera-space plane h . X = 1
  T normal[3];       // camera-space unit normal facing the camera
  T color[3];
  int32_t index;     // the triangle's row in the inputs (CUDA: where its max weight goes)
};

// Screen-space support rectangle [x0,x1) x [y0,y1) in pixels.
using TriRect = PixelRect;

// Gradient of the loss with respect to one triangle's PixelTri geometry. The
// normal's gradient is not a field: it is folded into h (fold_normal_grad()),
// since the normal is a function of h alone; that keeps the rows the CUDA
// backward adds up and the chain rule reads at 18 floats.
template <class T>
struct TriGrad {
  T s[2];
  T n[6];      // (nx_i, ny_i) for i = 0..2
  T h[3];
  T zlo, zhi;
  T color[3];
  T opacity, sigma;
};
constexpr int kTriGradSize = 18;  // number of T in TriGrad

// ---------------------------------------------------------------- projection
// World vertices (v[0..8], three xyz) -> camera space.
template <class T>
FLAT_HD void to_camera(const T* v, const CameraView<T>& cam, T c[3][3]) {
  for (int k = 0; k < 3; ++k)
    for (int r = 0; r < 3; ++r)
      c[k][r] = cam.R[3 * r] * v[3 * k] + cam.R[3 * r + 1] * v[3 * k + 1] + cam.R[3 * r + 2] * v[3 * k + 2] + cam.t[r];
}

// The projected triangle (paper eq. 1, pixel-centre convention): vertices q_k
// in pixels, edges e_i = q_{i+1} - q_i with lengths l_i, perimeter P and twice
// the signed area A2. Shared by the preprocessing's forward and backward.
template <class T>
struct ScreenTriangle {
  T q[3][2], e[3][2], l[3];
  T P, A2;
};

template <class T>
FLAT_HD ScreenTriangle<T> project_triangle(const T c[3][3], const CameraView<T>& cam) {
  ScreenTriangle<T> st;
  for (int i = 0; i < 3; ++i) {
    st.q[i][0] = cam.fx * c[i][0] / c[i][2] + cam.cx;
    st.q[i][1] = cam.fy * c[i][1] / c[i][2] + cam.cy;
  }
  for (int i = 0; i < 3; ++i) {
    const int j = (i + 1) % 3;
    st.e[i][0] = st.q[j][0] - st.q[i][0];
    st.e[i][1] = st.q[j][1] - st.q[i][1];
    st.l[i] = std::sqrt(st.e[i][0] * st.e[i][0] + st.e[i][1] * st.e[i][1]);
  }
  st.P = st.l[0] + st.l[1] + st.l[2];
  st.A2 = (st.q[1][0] - st.q[0][0]) * (st.q[2][1] - st.q[0][1]) - (st.q[1][1] - st.q[0][1]) * (st.q[2][0] - st.q[0][0]);
  return st;
}

// Forward of the per-(view, triangle) preprocessing. Returns false when the
// triangle is culled (docs/rasterizer.md, "Culling"); fills geometry of `out`
// (not colour/opacity/sigma), the support rectangle and the depth sort key.
template <class T>
FLAT_HD bool preprocess_forward(const T* v, const CameraView<T>& cam, const RasterConstants& k, int width,
                                int height, PixelTri<T>& out, TriRect& rect, T& key) {
  T c[3][3];
  to_camera(v, cam, c);
  for (int i = 0; i < 3; ++i)
    if (!(c[i][2] >= T(k.near_plane))) return false;  // behind or crossing the near plane (also NaN)
  // Edge-on: the plane normal is (almost) perpendicular to the view ray to the centroid.
  T a[3], b[3], N[3];
  for (int r = 0; r < 3; ++r) a[r] = c[1][r] - c[0][r], b[r] = c[2][r] - c[0][r];
  N[0] = a[1] * b[2] - a[2] * b[1];
  N[1] = a[2] * b[0] - a[0] * b[2];
  N[2] = a[0] * b[1] - a[1] * b[0];
  T cen[3];
  for (int r = 0; r < 3; ++r) cen[r] = (c[0][r] + c[1][r] + c[2][r]) / T(3);
  const T nN = std::sqrt(N[0] * N[0] + N[1] * N[1] + N[2] * N[2]);
  const T nC = std::sqrt(cen[0] * cen[0] + cen[1] * cen[1] + cen[2] * cen[2]);
  const T D = N[0] * c[0][0] + N[1] * c[0][1] + N[2] * c[0][2];
  const T Dc = N[0] * cen[0] + N[1] * cen[1] + N[2] * cen[2];
  if (!(nN > T(0)) || !(std::fabs(Dc) >= T(k.min_cos) * nN * nC)) return false;
  const ScreenTriangle<T> st = project_triangle(c, cam);
  const auto& q = st.q;
  const auto& e = st.e;
  const auto& l = st.l;
  const T P = st.P, A2 = st.A2;
  if (!(P > T(0)) || !(std::fabs(A2) >= T(k.min_inradius) * P)) return false;  // degenerate: rho < min_inradius
  const T K = P / A2;
  for (int i = 0; i < 3; ++i) {
    out.nx[i] = -K * e[i][1] / l[i];
    out.ny[i] = K * e[i][0] / l[i];
  }
  // Incenter: vertices weighted by the length of the opposite edge (q0 is opposite edge 1).
  out.sx = (l[1] * q[0][0] + l[2] * q[1][0] + l[0] * q[2][0]) / P;
  out.sy = (l[1] * q[0][1] + l[2] * q[1][1] + l[0] * q[2][1]) / P;
  for (int r = 0; r < 3; ++r) out.h[r] = N[r] / D;
  const T nh = std::sqrt(out.h[0] * out.h[0] + out.h[1] * out.h[1] + out.h[2] * out.h[2]);
  for (int r = 0; r < 3; ++r) out.normal[r] = -out.h[r] / nh;  // h points away from the camera
  out.zlo = tmin(c[0][2], tmin(c[1][2], c[2][2]));
  out.zhi = tmax(c[0][2], tmax(c[1][2], c[2][2]));
  key = cen[2];
  // Support: the triangle dilated about the incenter by (1 + eps) (FLAT) or the triangle (TS).
  const T grow = k.window == kWindowFlat ? T(1) + T(k.eps) : T(1);
  T lo[2] = {T(1e30), T(1e30)}, hi[2] = {T(-1e30), T(-1e30)};
  const T s[2] = {out.sx, out.sy};
  for (int i = 0; i < 3; ++i)
    for (int d = 0; d < 2; ++d) {
      const T p = s[d] + grow * (q[i][d] - s[d]);
      lo[d] = tmin(lo[d], p);
      hi[d] = tmax(hi[d], p);
    }
  return covered_pixels(lo, hi, width, height, rect);
}

// Reverse of preprocess_forward's geometry: gradient of the PixelTri geometry
// (g.s, g.n, g.h with the normal's folded in, g.zlo, g.zhi) -> gradient of the
// world vertices, added into gv[0..8]. Recomputes the forward intermediates.
template <class T>
FLAT_HD void preprocess_backward(const T* v, const CameraView<T>& cam, const TriGrad<T>& g, T* gv) {
  T c[3][3];
  to_camera(v, cam, c);
  T gc[3][3] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
  // --- camera-space plane and normal
  T a[3], b[3], N[3];
  for (int r = 0; r < 3; ++r) a[r] = c[1][r] - c[0][r], b[r] = c[2][r] - c[0][r];
  N[0] = a[1] * b[2] - a[2] * b[1];
  N[1] = a[2] * b[0] - a[0] * b[2];
  N[2] = a[0] * b[1] - a[1] * b[0];
  const T D = N[0] * c[0][0] + N[1] * c[0][1] + N[2] * c[0][2];
  T h[3], gh[3];
  for (int r = 0; r < 3; ++r) h[r] = N[r] / D, gh[r] = g.h[r];  // g.h holds the normal's gradient too
  // h = N / D, D = N . c0
  const T gD = -(gh[0] * h[0] + gh[1] * h[1] + gh[2] * h[2]) / D;
  T gN[3];
  for (int r = 0; r < 3; ++r) {
    gN[r] = gh[r] / D + gD * c[0][r];
    gc[0][r] += gD * N[r];
  }
  // N = a x b: ga = b x gN, gb = gN x a
  T ga[3], gb[3];
  ga[0] = b[1] * gN[2] - b[2] * gN[1];
  ga[1] = b[2] * gN[0] - b[0] * gN[2];
  ga[2] = b[0] * gN[1] - b[1] * gN[0];
  gb[0] = gN[1] * a[2] - gN[2] * a[1];
  gb[1] = gN[2] * a[0] - gN[0] * a[2];
  gb[2] = gN[0] * a[1] - gN[1] * a[0];
  for (int r = 0; r < 3; ++r) {
    gc[1][r] += ga[r];
    gc[2][r] += gb[r];
    gc[0][r] -= ga[r] + gb[r];
  }
  // depth range (first index on ties, as in the forward's min/max result)
  {
    int ilo = 0, ihi = 0;
    for (int i = 1; i < 3; ++i) {
      if (c[i][2] < c[ilo][2]) ilo = i;
      if (c[i][2] > c[ihi][2]) ihi = i;
    }
    gc[ilo][2] += g.zlo;
    gc[ihi][2] += g.zhi;
  }
  // --- screen-space window geometry
  const ScreenTriangle<T> st = project_triangle(c, cam);
  const auto& q = st.q;
  const auto& e = st.e;
  const auto& l = st.l;
  const T P = st.P, A2 = st.A2;
  const T K = P / A2;
  T gq[3][2] = {{0, 0}, {0, 0}, {0, 0}}, ge[3][2], gl[3];
  T gK = 0;
  for (int i = 0; i < 3; ++i) {
    const T gnx = g.n[2 * i], gny = g.n[2 * i + 1];
    // n_i = K * (-e.y, e.x) / l
    const T dot = (-gnx * e[i][1] + gny * e[i][0]) / l[i];
    gK += dot;
    ge[i][0] = K / l[i] * gny;
    ge[i][1] = -K / l[i] * gnx;
    gl[i] = -K / l[i] * dot;
  }
  T gP = gK / A2;
  const T gA2 = -gK * K / A2;
  // incenter s = (l1 q0 + l2 q1 + l0 q2) / P
  const T sx = (l[1] * q[0][0] + l[2] * q[1][0] + l[0] * q[2][0]) / P;
  const T sy = (l[1] * q[0][1] + l[2] * q[1][1] + l[0] * q[2][1]) / P;
  const int opp[3] = {1, 2, 0};  // vertex k is weighted by l[opp[k]]
  for (int kv = 0; kv < 3; ++kv) {
    gq[kv][0] += g.s[0] * l[opp[kv]] / P;
    gq[kv][1] += g.s[1] * l[opp[kv]] / P;
    gl[opp[kv]] += (g.s[0] * q[kv][0] + g.s[1] * q[kv][1]) / P;
  }
  gP += -(g.s[0] * sx + g.s[1] * sy) / P;
  for (int i = 0; i < 3; ++i) {
    gl[i] += gP;
    ge[i][0] += gl[i] * e[i][0] / l[i];
    ge[i][1] += gl[i] * e[i][1] / l[i];
    const int j = (i + 1) % 3;
    for (int d = 0; d < 2; ++d) {
      gq[j][d] += ge[i][d];
      gq[i][d] -= ge[i][d];
    }
  }
  // A2 = (q1-q0) x (q2-q0)
  const T g1x = gA2 * (q[2][1] - q[0][1]), g1y = -gA2 * (q[2][0] - q[0][0]);
  const T g2x = -gA2 * (q[1][1] - q[0][1]), g2y = gA2 * (q[1][0] - q[0][0]);
  gq[1][0] += g1x, gq[1][1] += g1y, gq[2][0] += g2x, gq[2][1] += g2y;
  gq[0][0] -= g1x + g2x, gq[0][1] -= g1y + g2y;
  // projection q = (fx x/z + cx, fy y/z + cy)
  for (int i = 0; i < 3; ++i) {
    const T z = c[i][2];
    gc[i][0] += gq[i][0] * cam.fx / z;
    gc[i][1] += gq[i][1] * cam.fy / z;
    gc[i][2] += -(gq[i][0] * cam.fx * c[i][0] + gq[i][1] * cam.fy * c[i][1]) / (z * z);
  }
  // c = R v + t  ->  gv = R^T gc
  for (int kv = 0; kv < 3; ++kv)
    for (int col = 0; col < 3; ++col)
      gv[3 * kv + col] += cam.R[col] * gc[kv][0] + cam.R[3 + col] * gc[kv][1] + cam.R[6 + col] * gc[kv][2];
}

// ---------------------------------------------------------------- window
// Its pow and log, the divisions and 1 / sqrt per (pixel, triangle) pair:
// window_pow, window_log, fast_div and fast_rsqrt of fast_math.h.

// The gradient gn of the camera-space normal (normal = -h / |h|) added into
// the gradient gh of the plane h: gh += -(gn - (gn . h) h / |h|^2) / |h|.
// Linear in gn: the rasterizers fold a triangle's summed normal gradient once
// (the CUDA backward once per tile half, before adding its row).
template <class T>
FLAT_HD void fold_normal_grad(const T h[3], const T gn[3], T gh[3]) {
  const T inv = fast_rsqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2]);  // 1 / |h|
  const T gn_dot_h = gn[0] * h[0] + gn[1] * h[1] + gn[2] * h[2];
  for (int r = 0; r < 3; ++r) gh[r] -= (gn[r] - gn_dot_h * inv * inv * h[r]) * inv;
}

// FLAT (paper eq. "Window Function"): I = prod_i clamp(u_i + eps, 0, 1)^sigma.
// TS (Triangle Splatting): I = (min_i u_i)^sigma inside, 0 outside.
template <class T>
FLAT_HD T window_forward(const T u[3], T sigma, T eps, int kind) {
  if (kind == kWindowFlat) {
    T prod = T(1);
    for (int i = 0; i < 3; ++i) prod *= tmin(tmax(u[i] + eps, T(0)), T(1));
    return prod > T(0) ? window_pow(prod, sigma) : T(0);
  }
  const T m = tmin(u[0], tmin(u[1], u[2]));
  return m > T(0) ? window_pow(m, sigma) : T(0);
}

// dI -> du (3) and dsigma, given I = window_forward(...).
template <class T>
FLAT_HD void window_backward(const T u[3], T sigma, T eps, int kind, T I, T gI, T gu[3], T& gsigma) {
  gu[0] = gu[1] = gu[2] = T(0);
  gsigma = T(0);
  if (!(I > T(0))) return;
  if (kind == kWindowFlat) {
    // dI/dsigma = I log(prod r_i): one log of the product, not three.
    T prod = T(1);
    for (int i = 0; i < 3; ++i) {
      const T r = tmin(u[i] + eps, T(1));  // > 0 since I > 0
      prod *= r;
      if (u[i] + eps < T(1)) gu[i] = fast_div(gI * sigma * I, r);  // clamp is flat above 1
    }
    gsigma = gI * I * window_log(prod);
    return;
  }
  int am = 0;  // the single minimal edge receives the gradient (as the reference)
  for (int i = 1; i < 3; ++i)
    if (u[i] < u[am]) am = i;
  gu[am] = fast_div(gI * sigma * I, u[am]);
  gsigma = gI * I * window_log(u[am]);
}

// ---------------------------------------------------------------- fragment
// Everything one pixel computes of one triangle; reused by the backward.
template <class T>
struct Fragment {
  T u[3];
  T I;       // window value
  T alpha;   // min(alpha_max, opacity * I)
  T z;       // ray-plane depth, clamped into [zlo, zhi]
  int zclamp;  // 0: exact, -1: clamped to zlo, +1: clamped to zhi
};

// px, py: pixel centre; rx, ry: camera ray direction (x, y) with z = 1.
template <class T>
FLAT_HD void shade(const PixelTri<T>& t, T px, T py, T rx, T ry, const RasterConstants& k, Fragment<T>& f) {
  const T dx = px - t.sx, dy = py - t.sy;
  for (int i = 0; i < 3; ++i) f.u[i] = T(1) + t.nx[i] * dx + t.ny[i] * dy;
  f.I = window_forward(f.u, t.sigma, T(k.eps), k.window);
  f.alpha = fragment_alpha(t.opacity, f.I, k);
}

template <class T>
FLAT_HD void fragment_depth(const PixelTri<T>& t, T rx, T ry, Fragment<T>& f) {
  const T invz = t.h[0] * rx + t.h[1] * ry + t.h[2];
  // Compare in inverse depth: also catches rays that miss the plane (invz <= 0).
  if (invz * t.zhi <= T(1)) {
    f.z = t.zhi, f.zclamp = 1;
  } else if (invz * t.zlo >= T(1)) {
    f.z = t.zlo, f.zclamp = -1;
  } else {
    f.z = fast_div(T(1), invz), f.zclamp = 0;
  }
}

}  // namespace flat::render
