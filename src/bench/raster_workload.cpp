#include "flat/bench/raster_workload.h"

#include <cmath>

#include <torch/torch.h>

#include "flat/core/error.h"

namespace flat::bench {
namespace {

constexpr double kPi = 3.14159265358979323846;

// The first intersection (camera-frame z, since dirs have camera z = 1) of
// rays from C inside the room box with its walls (raster_workload.py's
// _first_hit_depth, operation for operation).
at::Tensor first_hit_depth(const at::Tensor& C, const at::Tensor& dirs) {
  const auto o = dirs.options();
  const at::Tensor lo = torch::tensor({-3.0, -1.5, -4.0}, o), hi = torch::tensor({3.0, 1.5, 4.0}, o);
  const at::Tensor bound = torch::where(dirs > 0, hi, lo);
  const at::Tensor zero = dirs == 0;
  at::Tensor tt = (bound - C) / torch::where(zero, torch::full_like(dirs, 1e-30), dirs);
  tt = torch::where(zero, torch::full_like(tt, INFINITY), tt);
  return std::get<0>(tt.min(1));
}

at::Tensor unit_rows(const at::Tensor& x) { return x / at::linalg_vector_norm(x, 2, {1}, true); }

}  // namespace

AnchorCameraPath anchor_camera_path(int64_t frames, int64_t height, int64_t width) {
  // raster_workload.py camera_path: float64, then float32.
  const double fovx = 70.0 * kPi / 180.0;
  AnchorCameraPath path;
  path.focal = double(width) / (2.0 * std::tan(fovx / 2.0));
  (void)height;
  const auto d = torch::TensorOptions().dtype(torch::kFloat64);
  const at::Tensor t = torch::linspace(0.0, 1.0, frames, d);
  const at::Tensor s = t * t * (3.0 - 2.0 * t);
  const at::Tensor C = torch::stack({0.3 * torch::sin(kPi * t), torch::full_like(t, -0.1), -3.0 + 3.5 * s}, 1);
  const at::Tensor yaw = torch::deg2rad(-30.0 + 60.0 * s);
  const double pitch = 5.0 * kPi / 180.0, cp = std::cos(pitch), sp = std::sin(pitch);
  const at::Tensor cy = torch::cos(yaw), sy = torch::sin(yaw), zeros = torch::zeros_like(t), ones = torch::ones_like(t);
  const at::Tensor Ry = torch::stack({torch::stack({cy, zeros, sy}, -1), torch::stack({zeros, ones, zeros}, -1),
                                      torch::stack({-sy, zeros, cy}, -1)},
                                     -2);
  const at::Tensor Rx = torch::tensor({1.0, 0.0, 0.0, 0.0, cp, sp, 0.0, -sp, cp}, d).view({3, 3});
  const at::Tensor R = torch::matmul(Ry, Rx).to(torch::kFloat);
  path.c2w = torch::eye(4).repeat({frames, 1, 1});
  path.c2w.narrow(1, 0, 3).narrow(2, 0, 3).copy_(R);
  path.c2w.narrow(1, 0, 3).select(2, 3).copy_(C.to(torch::kFloat));
  return path;
}

RasterWorkload anchor_workload(const std::string& which, const at::Device& device, uint64_t seed) {
  int64_t frames = 0, H = 0, W = 0;
  std::vector<int64_t> targets;
  if (which == "large") {
    frames = 49, H = 432, W = 768;
    for (int64_t k = 1; k < 49; k += 2) targets.push_back(k);
  } else if (which == "small") {
    frames = 17, H = 320, W = 576;
    for (int64_t k = 0; k < 17; ++k) targets.push_back(k);
  } else {
    fail("anchor workload '" + which + "': expected large or small");
  }
  torch::NoGradGuard no_grad;
  // A fresh generator of the device's kind seeded like torch.Generator(device).manual_seed(seed).
  at::Generator gen = at::globalContext().defaultGenerator(device).clone();
  gen.set_current_seed(seed);
  const auto f32 = torch::TensorOptions().dtype(torch::kFloat).device(device);
  const AnchorCameraPath path = anchor_camera_path(frames, H, W);
  const double f = path.focal;
  const at::Tensor c2w = path.c2w.to(device);
  const int64_t th = H / 2, tw = W / 2;
  const auto grid = torch::meshgrid({torch::arange(th, f32), torch::arange(tw, f32)}, "ij");
  const at::Tensor u = 2.0 * grid[1] + 0.5, v = 2.0 * grid[0] + 0.5;
  const at::Tensor d_cam =
      torch::stack({(u - (W - 1) / 2.0) / f, (v - (H - 1) / 2.0) / f, torch::ones_like(u)}, -1).reshape({-1, 3});
  const int64_t M = d_cam.size(0);
  const at::Tensor ang0 = torch::tensor({0.0, 2.0 * kPi / 3.0, 4.0 * kPi / 3.0}, f32);
  std::vector<at::Tensor> verts;
  for (int64_t k = 0; k < frames; ++k) {
    const at::Tensor R = c2w[k].narrow(0, 0, 3).narrow(1, 0, 3), Ck = c2w[k].narrow(0, 0, 3).select(1, 3);
    const at::Tensor d_w = torch::matmul(d_cam, R.t());
    const at::Tensor z = first_hit_depth(Ck, d_w);
    const at::Tensor X = Ck + z.unsqueeze(1) * d_w;
    const at::Tensor n = unit_rows(d_w);  // faces the generating ray
    const at::Tensor y_cam = R.select(1, 1).expand_as(n);
    const at::Tensor e1 = unit_rows(at::linalg_cross(y_cam, n));
    const at::Tensor e2 = at::linalg_cross(n, e1);
    const at::Tensor r = 2.4 * z / f;  // circumradius 1.2 * 2 px at depth z
    const at::Tensor phi = torch::rand({M}, gen, f32) * (2.0 * kPi);
    const at::Tensor a = phi.unsqueeze(1) + ang0.unsqueeze(0);
    const at::Tensor off = torch::cos(a).unsqueeze(-1) * e1.unsqueeze(1) + torch::sin(a).unsqueeze(-1) * e2.unsqueeze(1);
    verts.push_back(X.unsqueeze(1) + r.view({-1, 1, 1}) * off);
  }
  RasterWorkload w;
  w.name = "anchor-" + which;
  w.vertices = torch::cat(verts, 0).contiguous();
  const int64_t P = w.vertices.size(0);
  w.colors = torch::rand({P, 3}, gen, f32);
  w.opacities = (0.3 + 0.6 * torch::rand({P, 1}, gen, f32)).view({P});
  w.sigmas = torch::ones({P}, f32);
  camera::Cameras all;
  all.intrinsics = torch::tensor({f / double(W), f / double(H), 0.5, 0.5}, torch::kFloat).repeat({frames, 1});
  all.c2w = path.c2w;
  w.targets = all.index(torch::tensor(targets, torch::kLong)).to(device);
  w.height = H;
  w.width = W;
  return w;
}

RasterWorkload room_workload(const std::string& name, int64_t frames, int64_t height, int64_t width,
                             int64_t target_views, const at::Device& device) {
  torch::NoGradGuard no_grad;
  auto f = torch::TensorOptions().dtype(torch::kFloat).device(device);
  const double fx_n = 0.6, fy_n = 0.6 * double(width) / double(height);
  camera::Cameras all;
  all.intrinsics = torch::tensor({fx_n, fy_n, 0.5, 0.5}, torch::kFloat).repeat({frames, 1});
  all.c2w = torch::eye(4).repeat({frames, 1, 1});
  for (int64_t t = 0; t < frames; ++t) {
    const double yaw = kPi * double(t) / double(std::max<int64_t>(frames - 1, 1));
    const double c = std::cos(yaw), s = std::sin(yaw);
    all.c2w[t].narrow(0, 0, 3).narrow(1, 0, 3).copy_(torch::tensor({{c, 0.0, s}, {0.0, 1.0, 0.0}, {-s, 0.0, c}}));
    all.c2w[t][0][3] = 0.5 * std::cos(2.0 * yaw);
    all.c2w[t][2][3] = 0.5 * std::sin(2.0 * yaw);
  }
  all = all.to(device);
  const int64_t h = height / 2, w = width / 2;
  // Rays through 2x2 block centres, camera space (z = 1).
  auto u = (torch::arange(w, f) * 2 + 1) / (fx_n * width) - 0.5 / fx_n;
  auto v = (torch::arange(h, f) * 2 + 1) / (fy_n * height) - 0.5 / fy_n;
  auto dcam = torch::stack({u.view({1, w}).expand({h, w}), v.view({h, 1}).expand({h, w}), torch::ones({h, w}, f)}, -1);
  auto R = all.c2w.narrow(1, 0, 3).narrow(2, 0, 3);  // (T,3,3)
  auto o = all.c2w.narrow(1, 0, 3).select(2, 3);     // (T,3)
  auto d = torch::einsum("tij,hwj->thwi", {R, dcam}); // (T,h,w,3), |d| >= 1
  auto half = torch::tensor({4.0, 1.5, 4.0}, f);
  auto oo = o.view({frames, 1, 1, 3});
  // Exit distance of the ray from inside the box: min over axes of (+-half - o)/d.
  auto tpos = (half - oo) / d, tneg = (-half - oo) / d;
  auto texit = torch::where(d > 0, tpos, tneg).nan_to_num(1e9, 1e9, 1e9).clamp_min(0).amin(-1);  // (T,h,w)
  auto centre = oo + texit.unsqueeze(-1) * d;
  // Triangles parallel to the image plane, sized from the pixel footprint.
  const double px_size = 1.0 / (fx_n * width);
  auto r_in = (texit * px_size).unsqueeze(-1);
  auto ex = R.select(2, 0).view({frames, 1, 1, 3}), ey = R.select(2, 1).view({frames, 1, 1, 3});
  std::vector<torch::Tensor> verts;
  for (int k = 0; k < 3; ++k) {
    const double ang = -kPi / 2 + 2.0 * kPi * k / 3.0;
    verts.push_back(centre + 2.0 * r_in * (std::cos(ang) * ex + std::sin(ang) * ey));  // circumradius 2 r_in
  }
  RasterWorkload sc;
  sc.name = name;
  sc.vertices = torch::stack(verts, -2).reshape({-1, 3, 3}).contiguous();
  const int64_t n = sc.vertices.size(0);
  sc.colors = torch::rand({n, 3}, f);
  sc.opacities = torch::rand({n}, f) * 0.6 + 0.3;
  sc.sigmas = torch::ones({n}, f);
  auto idx = torch::linspace(0, double(frames - 1), target_views).round().to(torch::kLong).to(device);
  sc.targets = all.index(idx);
  sc.height = height;
  sc.width = width;
  return sc;
}

}  // namespace flat::bench
