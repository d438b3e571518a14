// Ray-centred triangles: the paper's guarantees (positive area, centroid on the
// anchor ray at depth D, camera-facing at zero angles, coverage of the 2x2 block
// at initialisation), gradients, and the ablation variants.
#include <cmath>

#include "flat/camera/rays.h"
#include "flat/core/autocast_scope.h"
#include "flat/primitives/ray_triangles.h"
#include "primitive_cameras.h"
#include "test_support.h"

using namespace flat::primitives;
using flat::camera::Cameras;
using flat::test::make_cameras;

namespace {

at::Tensor normals_of(const at::Tensor& v) {  // (...,3,3) -> unit (...,3)
  auto n = at::cross(v.select(-2, 1) - v.select(-2, 0), v.select(-2, 2) - v.select(-2, 0), -1);
  return n / n.norm(2, -1, true);
}

at::Tensor areas_of(const at::Tensor& v) {
  auto vd = v.to(at::kDouble);
  return 0.5 * at::cross(vd.select(-2, 1) - vd.select(-2, 0), vd.select(-2, 2) - vd.select(-2, 0), -1).norm(2, -1);
}

constexpr int64_t B = 2, T = 2, H = 12, W = 16;

}  // namespace

TEST_CASE("triangle channel layout: 12 channels in the documented order", "[primitives]") {
  auto c = triangle_channels("ray_centred");
  CHECK(c.total == kDefaultHeadChannels);
  CHECK(c.depth == 0);
  CHECK(c.shape == 1);
  CHECK(c.rotation == 4);
  CHECK(c.colour == 7);
  CHECK(c.opacity == 10);
  CHECK(c.sigma == 11);
  CHECK(triangle_channels("three_offsets").total == 15);
  CHECK(triangle_channels("global_rotation").total == 13);
  auto sh = triangle_channels("ray_centred", 3);
  CHECK(sh.colour_count == 48);
  CHECK(sh.total == 12 - 3 + 48);
  REQUIRE_THROWS_WITH(triangle_channels("quaternion"), FLAT_CONTAINS("quaternion"));
}

TEST_CASE("ray-centred triangles have strictly positive area for any raw output", "[primitives]") {
  TriangleParamConfig cfg;
  auto cams = make_cameras(B * T);
  auto g = at::make_generator<at::CPUGeneratorImpl>(3);
  for (double spread : {1.0, 10.0, 60.0}) {
    auto raw = at::randn({B, 12, T, H / 2, W / 2}, g, at::kFloat) * spread;
    auto soup = build_triangles(raw, cams, H, W, cfg);
    REQUIRE(soup.vertices.sizes() == at::IntArrayRef({B, T * H / 2 * W / 2, 3, 3}));
    CHECK(at::isfinite(soup.vertices).all().item<bool>());
    CHECK(areas_of(soup.vertices).min().item<double>() > 0.0);
  }
  // Shape channels at the extremes: the diagonal floor keeps the area positive.
  for (double value : {-1e4, -80.0, 80.0}) {
    auto raw = at::zeros({B, 12, T, H / 2, W / 2});
    raw.narrow(1, 1, 3).fill_(value);
    auto soup = build_triangles(raw, cams, H, W, cfg);
    CHECK(areas_of(soup.vertices).min().item<double>() > 0.0);
  }
}

TEST_CASE("the centroid lies on the anchor ray at depth D", "[primitives]") {
  TriangleParamConfig cfg;
  cfg.depth_activation = "softplus";
  auto cams = make_cameras(B * T, at::kDouble);
  auto g = at::make_generator<at::CPUGeneratorImpl>(5);
  auto raw = at::randn({B, 12, T, H / 2, W / 2}, g, at::kDouble) * 2;
  auto soup = build_triangles(raw, cams, H, W, cfg);
  auto rays = flat::camera::pixel_rays(cams, H / 2, W / 2);
  auto o = rays.origins.reshape({B, -1, 3}), d = rays.directions.reshape({B, -1, 3});
  // D from the raw depth channel, independently: near + softplus(x + b), D(0) = depth_init.
  auto x = raw.select(1, 0).reshape({B, -1});
  double b = std::log(std::expm1(cfg.depth_init - cfg.depth_near));
  auto D = cfg.depth_near + at::softplus(x + b);
  auto centroid = soup.vertices.mean(-2);
  CHECK(flat::test::rel_error(centroid, o + D.unsqueeze(-1) * d) < 1e-12);
  // and the default sigmoid activation: Lyra's D = near (1-w) + far w, w = sigmoid(x - 1.65)
  TriangleParamConfig lyra;
  auto soup2 = build_triangles(raw, cams, H, W, lyra);
  auto w = at::sigmoid(x - 1.65);
  auto D2 = 0.1 * (1 - w) + 500.0 * w;
  CHECK(flat::test::rel_error(soup2.vertices.mean(-2), o + D2.unsqueeze(-1) * d) < 1e-12);
}

TEST_CASE("zero angles give a triangle facing the camera: normal parallel to the ray", "[primitives]") {
  TriangleParamConfig cfg;
  auto cams = make_cameras(B * T, at::kDouble);
  auto g = at::make_generator<at::CPUGeneratorImpl>(11);
  auto raw = at::randn({B, 12, T, H / 2, W / 2}, g, at::kDouble) * 3;
  raw.narrow(1, 4, 3).zero_();  // tilt_x, tilt_y, spin
  auto soup = build_triangles(raw, cams, H, W, cfg);
  auto d = flat::camera::pixel_rays(cams, H / 2, W / 2).directions.reshape({B, -1, 3});
  auto n = normals_of(soup.vertices);
  // Facing the camera: n = -d exactly (winding documented in triangle_soup.h).
  CHECK((n + d).abs().max().item<double>() < 1e-9);
  // Spin alone keeps the normal; a tilt turns it away from the ray by less than max_tilt.
  raw.narrow(1, 6, 1).fill_(2.0);
  n = normals_of(build_triangles(raw, cams, H, W, cfg).vertices);
  CHECK((n + d).abs().max().item<double>() < 1e-9);
  raw.narrow(1, 4, 1).fill_(0.5);
  n = normals_of(build_triangles(raw, cams, H, W, cfg).vertices);
  auto cos_angle = -(n * d).sum(-1);
  CHECK(cos_angle.max().item<double>() < 1 - 1e-3);
  double expected = std::cos(cfg.max_tilt * std::tanh(0.5));
  CHECK(cos_angle.min().item<double>() == Approx(expected).epsilon(1e-9));
}

TEST_CASE("at initialisation each triangle covers its 2x2 pixel block", "[primitives]") {
  // Definition tested: with raw = 0 the projection of the triangle into its own
  // frame's camera contains the four pixel corners of its block (block centre
  // +-1 px in x and y) and every edge is at least sqrt(2)*(1 - 2%) px away from
  // the block centre (the block's circumscribed circle, up to the
  // second-order perspective error of the first-order sizing).
  // Image 128x96 with fx/W in [0.7, 1.0] (up to ~71 deg field of view): focal
  // lengths of 90-160 px, so a ~3 px triangle is still small against them.
  const int64_t B = 1, T = 2, H = 96, W = 128;
  TriangleParamConfig cfg;
  cfg.depth_activation = "exp";
  auto cams = make_cameras(B * T, at::kDouble);
  auto raw = at::zeros({B, 12, T, H / 2, W / 2}, at::kDouble);
  raw.select(1, 0).copy_(at::linspace(-1.0, 1.0, T * (H / 2) * (W / 2), at::kDouble).view({T, H / 2, W / 2}));
  auto soup = build_triangles(raw, cams, H, W, cfg);
  // Project the vertices of token (b, t, i, j) with camera b*T + t.
  auto w2c = flat::camera::world_to_camera(cams.c2w).view({B, T, 1, 1, 4, 4});
  auto K = flat::camera::pixel_intrinsics(cams.intrinsics, H, W).view({B, T, 1, 1, 1, 4});
  auto v = soup.vertices.view({B, T, H / 2, W / 2, 3, 3});
  auto pc = at::matmul(w2c.narrow(-2, 0, 3).narrow(-1, 0, 3).unsqueeze(-3), v.unsqueeze(-1)).squeeze(-1) +
            w2c.narrow(-2, 0, 3).select(-1, 3).unsqueeze(-2);
  auto u = K.select(-1, 0) * pc.select(-1, 0) / pc.select(-1, 2) + K.select(-1, 2);
  auto vv = K.select(-1, 1) * pc.select(-1, 1) / pc.select(-1, 2) + K.select(-1, 3);
  auto q = at::stack({u, vv}, -1);  // (B,T,H2,W2,3 vertices,2)
  auto jj = at::arange(W / 2, at::kDouble).view({1, 1, 1, W / 2});
  auto ii = at::arange(H / 2, at::kDouble).view({1, 1, H / 2, 1});
  auto centre = at::stack({(2 * jj + 1).expand({B, T, H / 2, W / 2}), (2 * ii + 1).expand({B, T, H / 2, W / 2})}, -1);
  double min_corner_margin = 1e9, min_edge_distance = 1e9;
  for (int k = 0; k < 3; ++k) {
    auto a = q.select(-2, k), b = q.select(-2, (k + 1) % 3), c = q.select(-2, (k + 2) % 3);
    auto e = b - a;
    auto nrm = at::stack({-e.select(-1, 1), e.select(-1, 0)}, -1);
    nrm = nrm / nrm.norm(2, -1, true);
    auto side = ((c - a) * nrm).sum(-1).sign().unsqueeze(-1);
    nrm = nrm * side;  // points inwards
    auto dist_centre = ((centre - a) * nrm).sum(-1);
    min_edge_distance = std::min(min_edge_distance, dist_centre.min().item<double>());
    for (double sx : {-1.0, 1.0})
      for (double sy : {-1.0, 1.0}) {
        auto corner = centre + at::tensor({sx, sy}, at::kDouble);
        min_corner_margin = std::min(min_corner_margin, ((corner - a) * nrm).sum(-1).min().item<double>());
      }
  }
  INFO("min corner margin " << min_corner_margin << " px, min edge distance " << min_edge_distance << " px");
  CHECK(min_corner_margin > 0.0);
  CHECK(min_edge_distance > std::sqrt(2.0) * 0.98);
  CHECK(min_edge_distance < std::sqrt(2.0) * 1.25);  // covers, but not wildly oversized
}

TEST_CASE("gradient reaches every raw channel and matches finite differences", "[primitives]") {
  for (const char* param : {"ray_centred", "three_offsets", "global_rotation"}) {
    TriangleParamConfig cfg;
    cfg.parameterisation = param;
    cfg.depth_activation = "softplus";
    cfg.colour_activation = "sh";
    cfg.sh_degree = 1;
    const int64_t C = cfg.channels().total;
    auto cams = make_cameras(2, at::kDouble);
    auto g = at::make_generator<at::CPUGeneratorImpl>(13);
    auto raw = (0.5 * at::randn({1, C, 2, 1, 2}, g, at::kDouble)).requires_grad_(true);
    auto wv = at::randn({1, 4, 3, 3}, g, at::kDouble), wc = at::randn({1, 4, 4, 3}, g, at::kDouble);
    auto wo = at::randn({1, 4}, g, at::kDouble), ws = at::randn({1, 4}, g, at::kDouble);
    auto f = [&](const at::Tensor& r) {
      auto s = build_triangles(r, cams, 2, 4, cfg);
      return (s.vertices * wv).sum() + (s.colors * wc).sum() + (s.opacities * wo).sum() + (s.sigmas * ws).sum();
    };
    f(raw).backward();
    auto grad = raw.grad().clone();
    INFO(param);
    CHECK((grad.abs().sum({0, 2, 3, 4}) > 0).all().item<bool>());  // every channel
    auto fd = at::zeros_like(grad);
    auto flat_raw = raw.detach().clone().view(-1);
    auto fd_flat = fd.view(-1);
    const double h = 1e-6;
    for (int64_t k = 0; k < flat_raw.numel(); ++k) {
      auto p = flat_raw.clone(), m = flat_raw.clone();
      p[k] += h;
      m[k] -= h;
      fd_flat[k] = (f(p.view(raw.sizes())).item<double>() - f(m.view(raw.sizes())).item<double>()) / (2 * h);
    }
    CHECK(flat::test::rel_error(grad, fd) < 1e-7);
  }
}

TEST_CASE("ablation parameterisations produce valid triangles", "[primitives]") {
  auto cams = make_cameras(B * T);
  auto g = at::make_generator<at::CPUGeneratorImpl>(17);
  auto rays = flat::camera::pixel_rays(cams, H / 2, W / 2);
  auto d = rays.directions.reshape({B, -1, 3});

  TriangleParamConfig ours, offsets, global;
  offsets.parameterisation = "three_offsets";
  global.parameterisation = "global_rotation";

  // three_offsets at raw = 0 is the same initial triangle as ours.
  auto zero12 = at::zeros({B, 12, T, H / 2, W / 2});
  auto zero15 = at::zeros({B, 15, T, H / 2, W / 2});
  CHECK(flat::test::rel_error(build_triangles(zero15, cams, H, W, offsets).vertices,
                              build_triangles(zero12, cams, H, W, ours).vertices) < 1e-6);
  // With moderate random offsets: finite, non-degenerate, centroid still on the ray.
  auto raw15 = 0.3 * at::randn({B, 15, T, H / 2, W / 2}, g, at::kFloat);
  auto s15 = build_triangles(raw15, cams, H, W, offsets);
  CHECK(at::isfinite(s15.vertices).all().item<bool>());
  CHECK(areas_of(s15.vertices).min().item<double>() > 0.0);
  auto c15 = s15.vertices.mean(-2) - rays.origins.reshape({B, -1, 3});
  auto off_ray = at::cross(c15, d, -1).norm(2, -1) / c15.norm(2, -1);
  CHECK(off_ray.max().item<double>() < 1e-4);

  // global_rotation: identity quaternion at raw = 0 lays every triangle in the
  // world x-y plane (normal -z), whatever its ray; random quaternions stay valid.
  auto zero13 = at::zeros({B, 13, T, H / 2, W / 2});
  auto n = normals_of(build_triangles(zero13, cams, H, W, global).vertices);
  CHECK((n - at::tensor({0.f, 0.f, -1.f})).abs().max().item<double>() < 1e-5);
  auto raw13 = 3 * at::randn({B, 13, T, H / 2, W / 2}, g, at::kFloat);
  auto s13 = build_triangles(raw13, cams, H, W, global);
  CHECK(at::isfinite(s13.vertices).all().item<bool>());
  CHECK(areas_of(s13.vertices).min().item<double>() > 0.0);
}

TEST_CASE("colour, opacity and sigma activations respect their ranges", "[primitives]") {
  auto cams = make_cameras(B * T);
  auto g = at::make_generator<at::CPUGeneratorImpl>(19);
  auto raw = 20 * at::randn({B, 12, T, H / 2, W / 2}, g, at::kFloat);
  for (const char* act : {"sigmoid", "tanh"}) {
    TriangleParamConfig cfg;
    cfg.colour_activation = act;
    cfg.sigma_activation = std::string(act) == "tanh" ? "exp" : "softplus";
    auto s = build_triangles(raw.clamp(-30, 30), cams, H, W, cfg);
    CHECK(s.colors.sizes() == at::IntArrayRef({B, T * H / 2 * W / 2, 3}));
    CHECK(s.colors.min().item<float>() >= 0.f);
    CHECK(s.colors.max().item<float>() <= 1.f);
    CHECK(s.opacities.min().item<float>() >= 0.f);
    CHECK(s.opacities.max().item<float>() <= 1.f);
    CHECK(s.sigmas.min().item<float>() > 0.f);
  }
  TriangleParamConfig cfg;
  auto s0 = build_triangles(at::zeros({B, 12, T, H / 2, W / 2}), cams, H, W, cfg);
  CHECK(s0.sigmas.mean().item<float>() == Approx(cfg.sigma_init).epsilon(1e-5));
  CHECK(s0.opacities.mean().item<float>() == Approx(0.5).epsilon(1e-6));
  CHECK(s0.scene(1).vertices.sizes() == at::IntArrayRef({T * H / 2 * W / 2, 3, 3}));
}

TEST_CASE("build_triangles rejects bad input with a message naming it", "[primitives]") {
  TriangleParamConfig cfg;
  auto cams = make_cameras(B * T);
  REQUIRE_THROWS_WITH(build_triangles(at::zeros({B, 11, T, H / 2, W / 2}), cams, H, W, cfg),
                      FLAT_CONTAINS("(B,12,T,H/2,W/2)"));
  REQUIRE_THROWS_WITH(build_triangles(at::zeros({B, 12, T, H / 2, W / 2}), cams, H + 2, W, cfg),
                      FLAT_CONTAINS("half of the image size"));
  REQUIRE_THROWS_WITH(build_triangles(at::zeros({B, 12, T + 1, H / 2, W / 2}), cams, H, W, cfg),
                      FLAT_CONTAINS("cameras"));
  cfg.depth_far = 0.05;
  REQUIRE_THROWS_WITH(build_triangles(at::zeros({B, 12, T, H / 2, W / 2}), cams, H, W, cfg),
                      FLAT_CONTAINS("depth_far"));
}

TEST_CASE("triangle config from YAML", "[primitives]") {
  auto cfg = flat::config::parse<TriangleParamConfig>(
      "parameterisation: three_offsets\ndepth_activation: exp\ncolour_activation: sh\nsh_degree: 2\n", "tri.yaml");
  CHECK(cfg.channels().total == 1 + 6 + 3 + 27 + 1 + 1);
  REQUIRE_THROWS_WITH(flat::config::parse<TriangleParamConfig>("parameterisation: quats\n", "tri.yaml"),
                      FLAT_CONTAINS("parameterisation"));
}

TEST_CASE("half-precision head outputs build fp32 triangles", "[primitives]") {
  TriangleParamConfig cfg;
  auto cams = make_cameras(B * T);
  auto raw = at::zeros({B, 12, T, H / 2, W / 2}).to(at::kBFloat16).requires_grad_(true);
  auto soup = build_triangles(raw, cams, H, W, cfg);
  CHECK(soup.vertices.scalar_type() == at::kFloat);
  CHECK(flat::test::rel_error(soup.vertices, build_triangles(raw.detach().to(at::kFloat), cams, H, W, cfg).vertices) < 1e-6);
  soup.vertices.sum().backward();
  CHECK(raw.grad().scalar_type() == at::kBFloat16);
}

TEST_CASE("bf16 autocast leaves the triangle geometry in fp32", "[primitives]") {
  // Training runs the builder inside bf16 autocast (flat::AutocastScope); the
  // geometry must still be fp32: an at::matmul there would be cast to bf16
  // (~3 significant digits, vertices off by ~1e-2 relative).
  auto cams = make_cameras(B * T);
  auto g = at::make_generator<at::CPUGeneratorImpl>(23);
  for (const char* param : {"ray_centred", "three_offsets", "global_rotation"}) {
    TriangleParamConfig cfg;
    cfg.parameterisation = param;
    auto raw = at::randn({B, cfg.channels().total, T, H / 2, W / 2}, g, at::kFloat);
    auto plain = build_triangles(raw, cams, H, W, cfg);
    TriangleSoup mixed;
    {
      flat::AutocastScope autocast(true, at::kCPU);
      auto x = at::ones({2, 2});
      REQUIRE(at::matmul(x, x).scalar_type() == at::kBFloat16);  // the scope really casts matmul
      mixed = build_triangles(raw, cams, H, W, cfg);
    }
    INFO(param);
    CHECK(mixed.vertices.scalar_type() == at::kFloat);
    const double err = flat::test::rel_error(mixed.vertices, plain.vertices);
    INFO("vertex relative error under autocast " << err);
    CHECK(err < 1e-5);
  }
}
