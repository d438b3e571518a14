// Synthetic scenes: determinism, normals vs depth finite differences on planar
// surfaces, and multi-view depth consistency (frame A reprojected into B).
#include "flat/data/synthetic_scene.h"

#include <atomic>

#include "flat/camera/cameras.h"
#include "data_test_dirs.h"
#include "test_support.h"

using namespace flat;
using data::SynthOptions;

namespace {

SynthOptions opts(const std::string& family, const std::string& motion, uint64_t seed, int64_t h = 36, int64_t w = 48) {
  SynthOptions o;
  o.family = family;
  o.motion = motion;
  o.seed = seed;
  o.frames = 9;
  o.height = h;
  o.width = w;
  return o;
}

// Camera-space points (3,H,W) from z-depth (1,H,W) in double.
torch::Tensor backproject(const torch::Tensor& depth, const torch::Tensor& intr, int64_t H, int64_t W) {
  auto k = camera::pixel_intrinsics(intr.unsqueeze(0), H, W)[0].to(torch::kDouble);
  auto v = torch::arange(H, torch::kDouble).view({H, 1}).expand({H, W}) + 0.5;
  auto u = torch::arange(W, torch::kDouble).view({1, W}).expand({H, W}) + 0.5;
  auto z = depth[0].to(torch::kDouble);
  return torch::stack({z * (u - k[2]) / k[0], z * (v - k[3]) / k[1], z});
}

}  // namespace

TEST_CASE("synthetic scenes are deterministic by seed", "[data][synthetic]") {
  auto a = data::render_synthetic_scene(opts("room", "mixed", 7, 12, 16));
  auto b = data::render_synthetic_scene(opts("room", "mixed", 7, 12, 16));
  auto c = data::render_synthetic_scene(opts("room", "mixed", 8, 12, 16));
  CHECK(torch::equal(a.images, b.images));
  CHECK(torch::equal(a.depth, b.depth));
  CHECK(torch::equal(a.cameras.c2w, b.cameras.c2w));
  CHECK_FALSE(torch::equal(a.images, c.images));
  CHECK(a.images.min().item<float>() >= 0);
  CHECK(a.images.max().item<float>() <= 1);
  CHECK(a.images.sizes() == torch::IntArrayRef({9, 3, 12, 16}));
}

TEST_CASE("synthetic scenes: frames rendered in parallel equal frames rendered one by one", "[data][synthetic]") {
  auto o = opts("room", "mixed", 11, 12, 16);
  std::atomic<int> calls{0};
  o.on_frame = [&] { ++calls; };
  o.frame_threads = 1;
  auto one = data::render_synthetic_scene(o);
  CHECK(calls.load() == 9);
  o.frame_threads = 4;
  calls = 0;
  auto many = data::render_synthetic_scene(o);
  CHECK(calls.load() == 9);
  // Each frame in its place: the frames differ (the camera moves), and the
  // parallel output equals the sequential one bit for bit.
  CHECK_FALSE(torch::equal(one.images[0], one.images[8]));
  CHECK(torch::equal(one.images, many.images));
  CHECK(torch::equal(one.depth, many.depth));
  CHECK(torch::equal(one.normals, many.normals));
  CHECK(torch::equal(one.surface, many.surface));
}

TEST_CASE("synthetic normals agree with normals from depth finite differences on planes", "[data][synthetic]") {
  for (auto [family, motion] : {std::pair{"room", "pan"}, std::pair{"object", "orbit"}, std::pair{"room", "zoom"}}) {
    auto s = data::render_synthetic_scene(opts(family, motion, 3));
    const int64_t H = s.images.size(2), W = s.images.size(3);
    int64_t checked = 0;
    double worst = 0, sum = 0;
    for (int64_t f = 0; f < s.images.size(0); ++f) {
      auto P = backproject(s.depth[f], s.cameras.intrinsics[f], H, W);
      auto dx = P.slice(2, 2, W).slice(1, 1, H - 1) - P.slice(2, 0, W - 2).slice(1, 1, H - 1);
      auto dy = P.slice(1, 2, H).slice(2, 1, W - 1) - P.slice(1, 0, H - 2).slice(2, 1, W - 1);
      auto n = torch::cross(dx, dy, 0);
      n = n / n.norm(2, 0, true).clamp_min(1e-30);
      auto centre = P.slice(1, 1, H - 1).slice(2, 1, W - 1);
      n = n * torch::where((n * centre).sum(0, true) > 0, -1.0, 1.0);  // face the camera
      auto id = s.surface[f];
      auto c = id.slice(0, 1, H - 1).slice(1, 1, W - 1);
      // Planar pixels: the 4-neighbourhood lies on the same planar surface.
      auto same = (c >= 0) & (id.slice(0, 1, H - 1).slice(1, 2, W) == c) & (id.slice(0, 1, H - 1).slice(1, 0, W - 2) == c) &
                  (id.slice(0, 2, H).slice(1, 1, W - 1) == c) & (id.slice(0, 0, H - 2).slice(1, 1, W - 1) == c);
      auto planar = s.planar.index({c.clamp_min(0)}) & same;
      auto N = s.normals[f].to(torch::kDouble).slice(1, 1, H - 1).slice(2, 1, W - 1);
      auto err = (1 - (n * N).sum(0)).masked_select(planar);
      checked += err.numel();
      if (err.numel()) {
        worst = std::max(worst, err.max().item<double>());
        sum += err.sum().item<double>();
      }
      // Stored normals are unit length wherever something was hit.
      auto len = s.normals[f].norm(2, 0).masked_select(s.surface[f] >= 0);
      CHECK((len - 1).abs().max().item<float>() < 1e-4);
    }
    INFO(family << " " << motion << ": " << checked << " planar pixels, mean(1-cos) " << sum / checked
                << ", worst " << worst);
    CHECK(checked > 9 * 34 * 46 / 2);
    CHECK(sum / checked < 1e-5);
    CHECK(worst < 1e-3);  // about 2.5 degrees in float32 depth at grazing angles
  }
}

TEST_CASE("synthetic depth of frame A reprojected into frame B matches B's depth", "[data][synthetic]") {
  for (auto [family, motion] : {std::pair{"room", "pan"}, std::pair{"object", "orbit"}, std::pair{"object", "zoom"},
                                std::pair{"room", "orbit"}}) {
    auto s = data::render_synthetic_scene(opts(family, motion, 11));
    const int64_t H = s.images.size(2), W = s.images.size(3);
    for (auto [a, b] : {std::pair<int64_t, int64_t>{0, 1}, {4, 3}, {8, 7}}) {
      auto Pa = backproject(s.depth[a], s.cameras.intrinsics[a], H, W).reshape({3, -1});
      auto ca = s.cameras.c2w[a].to(torch::kDouble), cb = s.cameras.c2w[b].to(torch::kDouble);
      auto world = torch::matmul(ca.slice(0, 0, 3).slice(1, 0, 3), Pa) + ca.slice(0, 0, 3).slice(1, 3, 4);
      auto wb = camera::world_to_camera(cb.unsqueeze(0).to(torch::kFloat))[0].to(torch::kDouble);
      auto Pb = torch::matmul(wb.slice(0, 0, 3).slice(1, 0, 3), world) + wb.slice(0, 0, 3).slice(1, 3, 4);
      auto k = camera::pixel_intrinsics(s.cameras.intrinsics[b].unsqueeze(0), H, W)[0].to(torch::kDouble);
      auto z = Pb[2];
      auto u = k[0] * Pb[0] / z + k[2] - 0.5, v = k[1] * Pb[1] / z + k[3] - 0.5;  // pixel-index coordinates
      auto u0 = torch::floor(u), v0 = torch::floor(v);
      auto inside = (z > 0) & (u0 >= 0) & (v0 >= 0) & (u0 < W - 1) & (v0 < H - 1);
      auto ida = s.surface[a].reshape({-1});
      auto iu = u0.clamp(0, W - 2).to(torch::kLong), iv = v0.clamp(0, H - 2).to(torch::kLong);
      auto idb = s.surface[b].reshape({-1});
      auto at_b = [&](int64_t dv, int64_t du) { return (iv + dv) * W + (iu + du); };
      // Visible in B on the same planar surface at all 4 bilinear taps (then inverse depth is
      // affine in the pixel coordinates and bilinear interpolation of it is exact).
      auto ok = inside & (ida >= 0) & s.planar.index({ida.clamp_min(0)});
      for (auto [dv, du] : {std::pair{0, 0}, {0, 1}, {1, 0}, {1, 1}}) ok = ok & (idb.index({at_b(dv, du)}) == ida);
      auto inv = 1.0 / s.depth[b].reshape({-1}).to(torch::kDouble).clamp_min(1e-9);
      auto fu = u - u0, fv = v - v0;
      auto interp = inv.index({at_b(0, 0)}) * (1 - fu) * (1 - fv) + inv.index({at_b(0, 1)}) * fu * (1 - fv) +
                    inv.index({at_b(1, 0)}) * (1 - fu) * fv + inv.index({at_b(1, 1)}) * fu * fv;
      auto rel = ((1.0 / z) / interp - 1).abs().masked_select(ok);
      INFO(family << " " << motion << " frames " << a << "->" << b << ": " << rel.numel() << " pixels, max rel "
                  << (rel.numel() ? rel.max().item<double>() : -1.0));
      REQUIRE(rel.numel() > H * W / 8);
      CHECK(rel.max().item<double>() < 1e-4);
    }
  }
}

TEST_CASE("synthetic scenes: frames cast in batches of rays equal frames cast one by one", "[data][synthetic]") {
  // The batched maths (per-frame rotations, cosines to the optical axis, the
  // last, smaller batch) that a GPU runs, here on the CPU: 9 frames as 4 + 4 + 1.
  auto o = opts("room", "mixed", 17, 12, 16);
  auto one = data::render_synthetic_scene(o);
  o.frames_per_batch = 4;
  o.frame_threads = 2;
  std::atomic<int> calls{0};
  o.on_frame = [&] { ++calls; };
  auto batched = data::render_synthetic_scene(o);
  CHECK(calls.load() == 9);
  CHECK(torch::equal(one.surface, batched.surface));
  CHECK(torch::allclose(one.images, batched.images, 0, 1e-6));
  CHECK(torch::allclose(one.depth, batched.depth, 1e-6, 1e-6));
  CHECK(torch::allclose(one.normals, batched.normals, 0, 1e-6));
  o.frames_per_batch = -1;
  REQUIRE_THROWS_WITH(data::render_synthetic_scene(o), FLAT_CONTAINS("frames_per_batch"));
}

TEST_CASE("synthetic scenes cast on CUDA agree with the CPU's", "[data][synthetic][cuda]") {
  FLAT_REQUIRE_CUDA();
  auto o = opts("room", "mixed", 13, 72, 96);
  auto cpu = data::render_synthetic_scene(o);
  o.device = c10::Device(c10::kCUDA);
  auto gpu = data::render_synthetic_scene(o);
  REQUIRE(gpu.images.device().is_cpu());  // the outputs come back to the CPU
  REQUIRE(gpu.images.sizes() == cpu.images.sizes());
  CHECK(torch::equal(gpu.cameras.c2w, cpu.cameras.c2w));
  // A ray grazing a silhouette may hit the other surface under other rounding:
  // the surface ids agree almost everywhere, and where they do the pixels agree.
  auto same = gpu.surface.eq(cpu.surface);
  CHECK(same.to(torch::kFloat).mean().item<float>() > 0.995f);
  auto m = same.unsqueeze(1);
  CHECK(((gpu.images - cpu.images).abs() * m).max().item<float>() < 1e-4f);
  // A ray grazing a sphere puts its hit point, so its normal, at the mercy of
  // the quadratic's rounding (fused multiply-adds on the GPU): such pixels are
  // rare, the rest agree to float rounding.
  auto share_over = [&](const torch::Tensor& a, const torch::Tensor& b, float tol) {
    auto off = (((a - b).abs() * m).amax(1) > tol);
    return off.to(torch::kFloat).mean().item<float>();
  };
  CHECK(share_over(gpu.normals, cpu.normals, 1e-4f) < 1e-3f);
  CHECK(((gpu.normals - cpu.normals).abs() * m).max().item<float>() < 1e-2f);
  CHECK(share_over(gpu.depth, cpu.depth, 1e-4f * cpu.depth.max().item<float>()) < 1e-3f);
  CHECK(((gpu.depth - cpu.depth).abs() * m).max().item<float>() < 1e-2f * cpu.depth.max().item<float>());
}
