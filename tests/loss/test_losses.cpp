// Photometric, disparity, normal, opacity and 2DGS losses: values on hand-made
// cases and gradients against central finite differences in double.
#include <cmath>
#include <functional>

#include "flat/loss/depth.h"
#include "flat/loss/normal.h"
#include "flat/loss/opacity.h"
#include "flat/loss/photometric.h"
#include "flat/loss/regularisers_2dgs.h"
#include "test_support.h"

using namespace flat::loss;

namespace {

// d f / d x by central differences, entry by entry (x double, small).
at::Tensor finite_difference(const std::function<at::Tensor(const at::Tensor&)>& f, const at::Tensor& x,
                             double h = 1e-6) {
  auto base = x.detach().clone();
  auto g = at::zeros_like(base);
  auto bf = base.view(-1);
  auto gf = g.view(-1);
  for (int64_t k = 0; k < bf.numel(); ++k) {
    auto p = base.clone(), m = base.clone();
    p.view(-1)[k] += h;
    m.view(-1)[k] -= h;
    gf[k] = (f(p).item<double>() - f(m).item<double>()) / (2 * h);
  }
  return g;
}

at::Tensor autograd_gradient(const std::function<at::Tensor(const at::Tensor&)>& f, const at::Tensor& x) {
  auto v = x.detach().clone().requires_grad_(true);
  f(v).backward();
  return v.grad();
}

void check_gradient(const std::function<at::Tensor(const at::Tensor&)>& f, const at::Tensor& x,
                    double tol = 1e-6) {
  auto ga = autograd_gradient(f, x);
  auto gn = finite_difference(f, x);
  INFO("autograd " << ga.norm().item<double>() << " vs finite differences " << gn.norm().item<double>());
  CHECK(ga.abs().sum().item<double>() > 0);
  CHECK(flat::test::rel_error(ga, gn) < tol);
}

at::Generator gen(uint64_t seed) { return at::make_generator<at::CPUGeneratorImpl>(seed); }

}  // namespace

TEST_CASE("L2 photometric loss: value and gradient", "[loss]") {
  auto a = at::zeros({1, 3, 2, 2}, at::kDouble);
  auto b = at::zeros_like(a);
  b[0][0][0][0] = 1.0;
  b[0][2][1][1] = 0.5;
  CHECK(l2_loss(a, b).item<double>() == Approx((1.0 + 0.25) / 12.0));
  auto g = gen(1);
  auto x = at::rand({2, 3, 3, 4}, g, at::kDouble), t = at::rand({2, 3, 3, 4}, g, at::kDouble);
  check_gradient([&](const at::Tensor& v) { return l2_loss(v, t); }, x);
  REQUIRE_THROWS_WITH(l2_loss(x, t.narrow(3, 0, 3)), FLAT_CONTAINS("(2,3,3,3)"));
}

TEST_CASE("disparity loss: hand-made least-squares alignment", "[loss]") {
  // p = (0,1,2,3), g = (0,1,2,4): s = 6.5/5 = 1.3, t = 1.75 - 1.3*1.5 = -0.2,
  // aligned (-0.2, 1.1, 2.4, 3.7), |residuals| (0.2, 0.1, 0.4, 0.3), mean 0.25.
  auto p = at::tensor({0.0, 1.0, 2.0, 3.0}, at::kDouble).view({1, 1, 2, 2});
  auto g = at::tensor({0.0, 1.0, 2.0, 4.0}, at::kDouble).view({1, 1, 2, 2});
  CHECK(disparity_loss(p, g).item<double>() == Approx(0.25).epsilon(1e-12));
  // An affine copy of the target costs nothing.
  CHECK(disparity_loss(3 * g + 1, g).item<double>() == Approx(0.0).margin(1e-12));
  // Masked-out pixels do not count: drop the outlier 4 -> exact fit.
  auto mask = at::tensor({1, 1, 1, 0}).to(at::kBool).view({1, 1, 2, 2});
  CHECK(disparity_loss(p, g, mask).item<double>() == Approx(0.0).margin(1e-12));
}

TEST_CASE("disparity loss is invariant to scale and shift of the prediction", "[loss]") {
  auto g = gen(2);
  auto p = at::rand({3, 1, 5, 6}, g, at::kDouble), t = at::rand({3, 1, 5, 6}, g, at::kDouble) + 0.1;
  auto mask = at::rand({3, 1, 5, 6}, g, at::kDouble) > 0.3;
  const double base = disparity_loss(p, t, mask).item<double>();
  CHECK(base > 0.01);
  for (auto [s, sh] : {std::pair{5.0, -2.0}, std::pair{0.01, 7.0}, std::pair{-3.0, 0.5}})
    CHECK(disparity_loss(s * p + sh, t, mask).item<double>() == Approx(base).epsilon(1e-9));
}

TEST_CASE("disparity loss in float32 on a nearly constant disparity equals float64", "[loss]") {
  // A wall at 10 m +-1% seen by 2 images of 64x96 pixels: the disparity varies
  // by 2% around 0.1. Uncentred normal equations in float32 were off by up to
  // 16% here; the centred solve agrees with float64 to float32 rounding.
  auto g = gen(11);
  auto depth = 10.0 * (1.0 + 0.01 * (2 * at::rand({2, 1, 64, 96}, g, at::kDouble) - 1));
  auto target = 1.0 / depth;
  auto pred = 0.7 * target + 0.02 * at::rand({2, 1, 64, 96}, g, at::kDouble) * target;  // an imperfect fit
  const double reference = disparity_loss(pred, target).item<double>();
  const double single = disparity_loss(pred.to(at::kFloat), target.to(at::kFloat)).item<double>();
  CHECK(reference > 1e-5);
  CHECK(std::abs(single - reference) <= 1e-3 * reference);
}

TEST_CASE("disparity loss survives images without valid pixels", "[loss]") {
  auto g = gen(3);
  auto p = at::rand({2, 1, 4, 4}, g, at::kDouble), t = at::rand({2, 1, 4, 4}, g, at::kDouble);
  auto none = at::zeros({2, 1, 4, 4}, at::kBool);
  auto x = p.clone().requires_grad_(true);
  auto l = disparity_loss(x, t, none);
  CHECK(l.item<double>() == 0.0);
  l.backward();
  CHECK(at::isfinite(x.grad()).all().item<bool>());
  // Image 0 fully valid, image 1 empty: the loss is image 0's alone.
  auto half = none.clone();
  half[0].fill_(true);
  CHECK(disparity_loss(p, t, half).item<double>() ==
        Approx(disparity_loss(p.narrow(0, 0, 1), t.narrow(0, 0, 1)).item<double>()).epsilon(1e-12));
  // A constant prediction (singular system) gives finite values and gradients.
  auto c = at::full({1, 1, 4, 4}, 0.3, at::kDouble).requires_grad_(true);
  auto lc = disparity_loss(c, t.narrow(0, 0, 1));
  lc.backward();
  CHECK(std::isfinite(lc.item<double>()));
  CHECK(at::isfinite(c.grad()).all().item<bool>());
  // Non-finite targets under the mask are ignored.
  auto bad = t.clone();
  bad[1][0][0][0] = std::numeric_limits<double>::quiet_NaN();
  auto m = at::ones({2, 1, 4, 4}, at::kBool);
  m[1][0][0][0] = false;
  CHECK(std::isfinite(disparity_loss(p, bad, m).item<double>()));
}

TEST_CASE("disparity loss gradient matches finite differences", "[loss]") {
  auto g = gen(4);
  auto p = at::rand({2, 1, 3, 4}, g, at::kDouble) + 0.2, t = at::rand({2, 1, 3, 4}, g, at::kDouble);
  auto mask = at::rand({2, 1, 3, 4}, g, at::kDouble) > 0.2;
  check_gradient([&](const at::Tensor& v) { return disparity_loss(v, t, mask); }, p);
  // Through the depth -> disparity conversion too.
  check_gradient([&](const at::Tensor& v) { return disparity_loss(depth_to_disparity(v), t, mask); }, p + 1.0);
}

TEST_CASE("normal loss: masked mean of 1 - cos", "[loss]") {
  // Three pixels: alpha 0.9 / 0.9 / 0.2; cosines 1, 0 and (masked out) -1.
  auto n = at::zeros({1, 3, 1, 3}, at::kDouble);
  auto N = at::zeros({1, 3, 1, 3}, at::kDouble);
  n[0][2][0][0] = -2.0;  N[0][2][0][0] = -1.0;  // same direction (rendered not unit): cos 1
  n[0][0][0][1] = 0.5;   N[0][2][0][1] = -1.0;  // perpendicular: cos 0
  n[0][2][0][2] = 1.0;   N[0][2][0][2] = -1.0;  // opposite, but alpha 0.2: masked
  auto alpha = at::tensor({0.9, 0.9, 0.2}, at::kDouble).view({1, 1, 1, 3});
  CHECK(normal_loss(n, N, alpha).item<double>() == Approx(0.5));
  // No valid pixel: 0.
  CHECK(normal_loss(n, N, at::zeros_like(alpha)).item<double>() == 0.0);
  auto g = gen(5);
  auto x = at::randn({2, 3, 3, 3}, g, at::kDouble), t = at::randn({2, 3, 3, 3}, g, at::kDouble);
  auto a = at::rand({2, 1, 3, 3}, g, at::kDouble);
  check_gradient([&](const at::Tensor& v) { return normal_loss(v, t, a); }, x);
}

TEST_CASE("opacity regulariser: L1 mean", "[loss]") {
  auto o = at::tensor({0.0, 0.5, 1.0, 0.25}, at::kDouble);
  CHECK(opacity_loss(o).item<double>() == Approx(0.4375));
  auto g = gen(6);
  check_gradient([](const at::Tensor& v) { return opacity_loss(v); }, at::rand({2, 5}, g, at::kDouble) + 0.01);
}

TEST_CASE("normals from depth: planes give their analytic normal", "[loss]") {
  const int64_t H = 6, W = 7;
  auto K = at::tensor({0.9, 1.1, 0.45, 0.55}, at::kDouble).view({1, 4});
  // Fronto-parallel plane z = 2: normal (0,0,-1) facing the camera.
  auto n = normals_from_depth(at::full({1, 1, H, W}, 2.0, at::kDouble), K);
  auto inner = n.narrow(2, 1, H - 2).narrow(3, 1, W - 2);
  CHECK((inner - at::tensor({0.0, 0.0, -1.0}, at::kDouble).view({1, 3, 1, 1})).abs().max().item<double>() < 1e-12);
  CHECK(n.narrow(2, 0, 1).abs().max().item<double>() == 0.0);  // border left at 0
  // Tilted plane a.P = 1 with a = (0.2, -0.1, 0.5): z = 1 / (a . (x, y, 1)).
  const double fx = 0.9 * W, fy = 1.1 * H, cx = 0.45 * W, cy = 0.55 * H;
  auto u = (at::arange(W, at::kDouble) + 0.5 - cx) / fx, v = (at::arange(H, at::kDouble) + 0.5 - cy) / fy;
  auto z = 1.0 / (0.2 * u.view({1, W}) - 0.1 * v.view({H, 1}) + 0.5);
  auto nt = normals_from_depth(z.view({1, 1, H, W}), K).narrow(2, 1, H - 2).narrow(3, 1, W - 2);
  auto expected = -at::tensor({0.2, -0.1, 0.5}, at::kDouble) / std::sqrt(0.04 + 0.01 + 0.25);
  CHECK((nt - expected.view({1, 3, 1, 1})).abs().max().item<double>() < 1e-9);
}

TEST_CASE("2DGS normal consistency: zero on a consistent plane, gradients", "[loss]") {
  const int64_t H = 5, W = 6;
  auto K = at::tensor({0.8, 0.9, 0.5, 0.5}, at::kDouble).view({1, 4});
  auto depth = at::full({1, 1, H, W}, 3.0, at::kDouble);
  auto normal = at::zeros({1, 3, H, W}, at::kDouble);
  normal.select(1, 2).fill_(-1.0);
  auto alpha = at::ones({1, 1, H, W}, at::kDouble);
  CHECK(normal_consistency_loss(normal, depth, alpha, K).item<double>() == Approx(0.0).margin(1e-12));
  // Perpendicular rendered normals: 1 everywhere.
  auto side = at::zeros_like(normal);
  side.select(1, 0).fill_(1.0);
  CHECK(normal_consistency_loss(side, depth, alpha, K).item<double>() == Approx(1.0));
  auto g = gen(7);
  auto d = 2.0 + at::rand({1, 1, H, W}, g, at::kDouble);
  auto nr = at::randn({1, 3, H, W}, g, at::kDouble);
  auto a = at::rand({1, 1, H, W}, g, at::kDouble);
  check_gradient([&](const at::Tensor& v) { return normal_consistency_loss(v, d, a, K); }, nr);
  check_gradient([&](const at::Tensor& v) { return normal_consistency_loss(nr, v, a, K); }, d, 1e-5);
}

TEST_CASE("2DGS depth distortion: reference on a hand case, gradients", "[loss]") {
  const double near = 0.2, far = 100.0;
  auto m = [&](double z) { return (far * z - far * near) / ((far - near) * z); };
  auto w = at::tensor({0.5, 0.3, 0.0, 0.0, 0.6, 0.4}, at::kDouble).view({2, 3});
  auto z = at::tensor({1.0, 2.0, 5.0, 1.0, 1.0, 4.0}, at::kDouble).view({2, 3});
  auto r = depth_distortion_reference(w, z, near, far);
  CHECK(r[0].item<double>() == Approx(0.5 * 0.3 * std::pow(m(1) - m(2), 2)).epsilon(1e-12));
  CHECK(r[1].item<double>() == Approx(0.6 * 0.4 * std::pow(m(1) - m(4), 2)).epsilon(1e-12));
  auto g = gen(8);
  auto wr = at::rand({4, 5}, g, at::kDouble) * 0.3;
  auto zr = 0.5 + at::rand({4, 5}, g, at::kDouble) * 5;
  check_gradient([&](const at::Tensor& v) { return depth_distortion_reference(v, zr).sum(); }, wr);
  check_gradient([&](const at::Tensor& v) { return depth_distortion_reference(wr, v).sum(); }, zr);
  auto map = at::tensor({0.1, 0.3, 0.2, 0.2}, at::kDouble).view({1, 1, 2, 2});
  CHECK(depth_distortion_loss(map).item<double>() == Approx(0.2));
}
