// Window functions (paper, Method, "Window Function") through the shared maths.
#include <cmath>

#include "flat/render/shared/triangle_math.h"
#include "test_support.h"

using namespace flat::render;

namespace {

// Identity camera, f = 100 px, principal point (50, 50); a fronto-parallel
// triangle at z = 1 whose projected vertices are (x, y) in pixels.
PixelTri<double> make_tri(const double q[3][2], int window, double eps, CameraView<double>& cam) {
  for (int i = 0; i < 9; ++i) cam.R[i] = (i % 4 == 0) ? 1.0 : 0.0;
  cam.t[0] = cam.t[1] = cam.t[2] = 0.0;
  cam.fx = cam.fy = 100.0;
  cam.cx = cam.cy = 50.0;
  double v[9];
  for (int k = 0; k < 3; ++k) v[3 * k] = (q[k][0] - 50.0) / 100.0, v[3 * k + 1] = (q[k][1] - 50.0) / 100.0, v[3 * k + 2] = 1.0;
  RasterConstants k;
  k.window = window;
  k.eps = (float)eps;
  PixelTri<double> t{};
  TriRect r{};
  double key = 0;
  REQUIRE(preprocess_forward(v, cam, k, 100, 100, t, r, key));
  t.sigma = 1.0;
  t.opacity = 1.0;
  return t;
}

double window_at(const PixelTri<double>& t, double x, double y, int window, double eps) {
  double u[3];
  for (int i = 0; i < 3; ++i) u[i] = 1.0 + t.nx[i] * (x - t.sx) + t.ny[i] * (y - t.sy);
  return window_forward(u, t.sigma, eps, window);
}

}  // namespace

TEST_CASE("window: incenter and inradius of a 3-4-5 right triangle", "[render][window]") {
  const double q[3][2] = {{10, 10}, {40, 10}, {10, 50}};  // legs 30 and 40: inradius 10, incenter (20, 20)
  CameraView<double> cam;
  auto t = make_tri(q, kWindowFlat, 0.1, cam);
  CHECK(t.sx == Approx(20.0).epsilon(1e-12));
  CHECK(t.sy == Approx(20.0).epsilon(1e-12));
  for (int i = 0; i < 3; ++i) CHECK(std::hypot(t.nx[i], t.ny[i]) == Approx(1.0 / 10.0).epsilon(1e-12));  // |n_i| = 1/rho
  CHECK(t.normal[2] == Approx(-1.0));  // facing the camera
  CHECK(t.h[2] == Approx(1.0));        // plane z = 1
}

TEST_CASE("window: FLAT is 1 at the incenter, 0 outside the eps-dilated triangle, differentiable just outside", "[render][window]") {
  const double q[3][2] = {{10, 10}, {40, 10}, {10, 50}};
  const double eps = 0.1;
  CameraView<double> cam;
  auto t = make_tri(q, kWindowFlat, eps, cam);
  for (double sigma : {0.5, 1.0, 3.0}) {
    t.sigma = sigma;
    CHECK(window_at(t, 20, 20, kWindowFlat, eps) == Approx(1.0).epsilon(1e-12));
  }
  t.sigma = 1.0;
  // Edge y = 10 (inside is y > 10): rho = 10, so the support ends at y = 10 - eps * rho = 9.
  CHECK(window_at(t, 20, 9.0 - 1e-6, kWindowFlat, eps) == 0.0);
  CHECK(window_at(t, 20, 8.0, kWindowFlat, eps) == 0.0);
  const double just_out = window_at(t, 20, 9.5, kWindowFlat, eps);
  CHECK(just_out > 0.0);
  // Gradient just outside the edge is non-zero for the sigma and all three u_i in the clamp's open range.
  double u[3];
  for (int i = 0; i < 3; ++i) u[i] = 1.0 + t.nx[i] * (20 - t.sx) + t.ny[i] * (9.5 - t.sy);
  double gu[3], gs;
  window_backward(u, 1.0, eps, kWindowFlat, just_out, 1.0, gu, gs);
  double norm = std::fabs(gu[0]) + std::fabs(gu[1]) + std::fabs(gu[2]);
  CHECK(norm > 0.0);
  CHECK(gs != 0.0);
  // Beyond the dilated vertex region the window vanishes too.
  CHECK(window_at(t, 5, 5, kWindowFlat, eps) == 0.0);
  CHECK(window_at(t, 45, 50, kWindowFlat, eps) == 0.0);
}

TEST_CASE("window: Triangle Splatting window is (min u)^sigma inside and 0 outside", "[render][window]") {
  const double q[3][2] = {{10, 10}, {40, 10}, {10, 50}};
  CameraView<double> cam;
  auto t = make_tri(q, kWindowTS, 0.0, cam);
  t.sigma = 2.0;
  CHECK(window_at(t, 20, 20, kWindowTS, 0.0) == Approx(1.0).epsilon(1e-12));
  CHECK(window_at(t, 20, 15, kWindowTS, 0.0) == Approx(0.25).epsilon(1e-12));  // distance 5 to edge y=10: (5/10)^2
  CHECK(window_at(t, 20, 9.5, kWindowTS, 0.0) == 0.0);
  // Gradient goes to the single minimal edge.
  double u[3];
  for (int i = 0; i < 3; ++i) u[i] = 1.0 + t.nx[i] * (20 - t.sx) + t.ny[i] * (15 - t.sy);
  double gu[3], gs;
  window_backward(u, 2.0, 0.0, kWindowTS, 0.25, 1.0, gu, gs);
  int nonzero = (gu[0] != 0) + (gu[1] != 0) + (gu[2] != 0);
  CHECK(nonzero == 1);
}

TEST_CASE("window: FLAT window gradients match finite differences in u and sigma", "[render][window]") {
  const double eps = 0.1;
  const double us[][3] = {{0.3, 0.5, 0.7}, {-0.05, 0.6, 0.85}, {0.95, 0.2, 0.4}};
  for (const auto& u0 : us)
    for (int kind : {kWindowFlat, kWindowTS}) {
      const double sigma = 1.7;
      const double I = window_forward(u0, sigma, eps, kind);
      double gu[3], gs;
      window_backward(u0, sigma, eps, kind, I, 1.0, gu, gs);
      const double h = 1e-7;
      for (int i = 0; i < 3; ++i) {
        double up[3] = {u0[0], u0[1], u0[2]}, um[3] = {u0[0], u0[1], u0[2]};
        up[i] += h, um[i] -= h;
        const double fd = (window_forward(up, sigma, eps, kind) - window_forward(um, sigma, eps, kind)) / (2 * h);
        CHECK(gu[i] == Approx(fd).margin(1e-6));
      }
      const double fds = (window_forward(u0, sigma + h, eps, kind) - window_forward(u0, sigma - h, eps, kind)) / (2 * h);
      CHECK(gs == Approx(fds).margin(1e-6));
    }
}
