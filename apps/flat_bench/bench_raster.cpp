// flat_bench raster: forward and forward+backward time (median) and peak GPU
// memory of the triangle rasterizer at the paper's sizes, on a synthetic
// "decoded scene": for each of T frames, one camera-facing triangle per 2x2
// pixel block on the walls of a box room (the anchor workload of the issue),
// rendered into every other camera (--workload paper|stage1|both). Or any PLY +
// cameras JSON. --device auto|cpu|cuda (peak memory is reported on CUDA only).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>

#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDACachingAllocator.h>
#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>
#include <torch/csrc/autograd/profiler_kineto.h>
#include <torch/torch.h>

#include "bench_registry.h"
#include "flat/camera/camera_json.h"
#include "flat/core/cli.h"
#include "flat/core/device_memory.h"
#include "flat/core/error.h"
#include "flat/export/triangle_ply.h"
#include "flat/render/rasterize.h"

namespace flat::bench {
namespace {

struct Scene {
  torch::Tensor vertices, colors, opacities, sigmas;
  camera::Cameras targets;
  int64_t height = 0, width = 0;
};

// T cameras at the room centre panning 180 degrees; each 2x2 block's centre
// ray hits the walls of the box [-4,4] x [-1.5,1.5] x [-4,4]; a camera-facing
// equilateral triangle of inradius ~1 px sits there. Targets: every other frame.
Scene room_scene(int64_t frames, int64_t height, int64_t width, int64_t target_views, const torch::Device& dev) {
  auto f = torch::TensorOptions().dtype(torch::kFloat).device(dev);
  const double fx_n = 0.6, fy_n = 0.6 * double(width) / double(height);
  camera::Cameras all;
  all.intrinsics = torch::tensor({fx_n, fy_n, 0.5, 0.5}, torch::kFloat).repeat({frames, 1});
  all.c2w = torch::eye(4).repeat({frames, 1, 1});
  for (int64_t t = 0; t < frames; ++t) {
    const double yaw = M_PI * double(t) / double(std::max<int64_t>(frames - 1, 1));
    const double c = std::cos(yaw), s = std::sin(yaw);
    all.c2w[t].narrow(0, 0, 3).narrow(1, 0, 3).copy_(torch::tensor({{c, 0.0, s}, {0.0, 1.0, 0.0}, {-s, 0.0, c}}));
    all.c2w[t][0][3] = 0.5 * std::cos(2.0 * yaw);
    all.c2w[t][2][3] = 0.5 * std::sin(2.0 * yaw);
  }
  all = all.to(dev);
  const int64_t h = height / 2, w = width / 2;
  // Anchor rays through 2x2 block centres, camera space (z = 1).
  auto u = (torch::arange(w, f) * 2 + 1) / (fx_n * width) - 0.5 / fx_n;
  auto v = (torch::arange(h, f) * 2 + 1) / (fy_n * height) - 0.5 / fy_n;
  auto dcam = torch::stack({u.view({1, w}).expand({h, w}), v.view({h, 1}).expand({h, w}), torch::ones({h, w}, f)}, -1);
  auto R = all.c2w.narrow(1, 0, 3).narrow(2, 0, 3);                           // (T,3,3)
  auto o = all.c2w.narrow(1, 0, 3).select(2, 3);                              // (T,3)
  auto d = torch::einsum("tij,hwj->thwi", {R, dcam});                         // (T,h,w,3), |d| >= 1
  auto half = torch::tensor({4.0, 1.5, 4.0}, f);
  auto oo = o.view({frames, 1, 1, 3});
  // Exit distance of the ray from inside the box: min over axes of (+-half - o)/d.
  auto tpos = (half - oo) / d, tneg = (-half - oo) / d;
  auto texit = torch::where(d > 0, tpos, tneg).nan_to_num(1e9, 1e9, 1e9).clamp_min(0).amin(-1);  // (T,h,w)
  auto centre = oo + texit.unsqueeze(-1) * d;                                  // world
  // Camera-facing frame: axes = camera x / y rotated to world; size from the pixel footprint.
  const double px_size = 1.0 / (fx_n * width);                                 // camera-plane size of a pixel at z = 1
  auto r_in = (texit * px_size).unsqueeze(-1);                                 // inradius ~ 1 px (z = texit for z-component 1)
  auto ex = R.select(2, 0).view({frames, 1, 1, 3}), ey = R.select(2, 1).view({frames, 1, 1, 3});
  std::vector<torch::Tensor> verts;
  for (int k = 0; k < 3; ++k) {
    const double ang = -M_PI / 2 + 2.0 * M_PI * k / 3.0;
    verts.push_back(centre + 2.0 * r_in * (std::cos(ang) * ex + std::sin(ang) * ey));  // circumradius 2 r_in
  }
  Scene sc;
  sc.vertices = torch::stack(verts, -2).reshape({-1, 3, 3}).contiguous();
  const int64_t n = sc.vertices.size(0);
  sc.colors = torch::rand({n, 3}, f);
  sc.opacities = torch::rand({n}, f) * 0.6 + 0.3;
  sc.sigmas = torch::ones({n}, f);
  auto idx = torch::linspace(0, double(frames - 1), target_views).round().to(torch::kLong).to(dev);
  sc.targets = all.index(idx);
  sc.height = height;
  sc.width = width;
  return sc;
}

double now_ms() {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// One forward+backward step under the libtorch (Kineto) profiler: GPU time per
// kernel name, summed over the step (where the time goes, without nsys).
void profile_scene(const std::string& label, const Scene& sc, const render::RasterSettings& settings) {
  namespace prof = torch::autograd::profiler;
  using torch::profiler::impl::ActivityType;
  auto v = sc.vertices.detach().requires_grad_(true), c = sc.colors.detach().requires_grad_(true);
  auto o = sc.opacities.detach().requires_grad_(true), s = sc.sigmas.detach().requires_grad_(true);
  const torch::profiler::impl::ProfilerConfig cfg(torch::profiler::impl::ProfilerState::KINETO);
  const std::set<ActivityType> acts = {ActivityType::CPU, ActivityType::CUDA};
  prof::prepareProfiler(cfg, acts);
  torch::cuda::synchronize();
  prof::enableProfiler(cfg, acts);
  auto r = render::rasterize(v, c, o, s, sc.targets, sc.height, sc.width, settings);
  (r.rgb.sum() + r.alpha.sum() + r.depth.sum() + r.normal.sum()).backward();
  torch::cuda::synchronize();
  const auto result = prof::disableProfiler();
  std::map<std::string, std::pair<double, int>> per_kernel;  // name -> (ms, launches)
  double total = 0;
  for (const auto& e : result->events()) {
    if (e.deviceType() != c10::DeviceType::CUDA) continue;
    auto& k = per_kernel[e.name().substr(0, 60)];
    k.first += e.durationNs() * 1e-6;
    k.second += 1;
    total += e.durationNs() * 1e-6;
  }
  std::vector<std::pair<double, std::string>> rows;
  for (const auto& [name, k] : per_kernel) rows.push_back({k.first, name + " x" + std::to_string(k.second)});
  std::sort(rows.rbegin(), rows.rend());
  std::printf("profile %s (one fwd+bwd step, GPU ms per kernel, total %.2f):\n", label.c_str(), total);
  for (size_t i = 0; i < rows.size() && i < 14; ++i) std::printf("  %8.2f  %s\n", rows[i].first, rows[i].second.c_str());
}

void time_scene(const std::string& label, const Scene& sc, const render::RasterSettings& settings, int repeats) {
  const auto dev = sc.vertices.device();
  auto sync = [&] {
    if (dev.is_cuda()) torch::cuda::synchronize();
  };
  const int64_t V = sc.targets.size();
  // Random upstream weights so every output carries gradient.
  auto w_rgb = torch::rand({V, 3, sc.height, sc.width}, sc.vertices.options());
  std::vector<double> fwd, fwdbwd;
  double peak_fwd = 0, peak_all = 0;
  int64_t visible = 0;
  for (int it = 0; it < repeats + 2; ++it) {
    {
      torch::NoGradGuard ng;
      sync();
      reset_peak_memory(dev);
      const double t0 = now_ms();
      auto r = render::rasterize(sc.vertices, sc.colors, sc.opacities, sc.sigmas, sc.targets, sc.height, sc.width,
                                 settings);
      sync();
      const double t1 = now_ms();
      if (it >= 2) fwd.push_back(t1 - t0);
      peak_fwd = std::max(peak_fwd, peak_memory_gib(dev));
      if (it == 0) visible = (r.max_weight > 0).sum().item<int64_t>();
    }
    auto v = sc.vertices.detach().requires_grad_(true), c = sc.colors.detach().requires_grad_(true);
    auto o = sc.opacities.detach().requires_grad_(true), s = sc.sigmas.detach().requires_grad_(true);
    sync();
    reset_peak_memory(dev);
    const double t0 = now_ms();
    auto r = render::rasterize(v, c, o, s, sc.targets, sc.height, sc.width, settings);
    auto loss = (r.rgb * w_rgb).sum() + r.alpha.sum() + 0.1 * r.depth.sum() + r.normal.sum();
    loss.backward();
    sync();
    const double t1 = now_ms();
    if (it >= 2) fwdbwd.push_back(t1 - t0);
    peak_all = std::max(peak_all, peak_memory_gib(dev));
  }
  const double gib = 1.0;  // peak_memory_gib is in GiB already
  spdlog::info("raster {}: {} triangles ({} with weight > 0), {} views at {}x{}, window {}", label,
               sc.vertices.size(0), visible, V, sc.height, sc.width, settings.window);
  spdlog::info("raster {}: forward {:.2f} ms (median of {}), forward+backward {:.2f} ms, peak {:.2f} GiB forward, "
               "{:.2f} GiB forward+backward",
               label, median(fwd), repeats, median(fwdbwd), peak_fwd / gib, peak_all / gib);
  std::printf("| %s | %lld | %lld | %lldx%lld | %s | %.2f | %.2f | %.2f |\n", label.c_str(),
              (long long)sc.vertices.size(0), (long long)V, (long long)sc.height, (long long)sc.width,
              settings.window.c_str(), median(fwd), median(fwdbwd), peak_all / gib);
}

}  // namespace

void add_raster(CLI::App& app) {
  auto* sub = app.add_subcommand("raster", "triangle rasterizer: forward, forward+backward time and peak memory");
  struct Opts {
    std::string workload = "both", ply, cams, window = "flat", device = "auto";
    int repeats = 5;
    bool profile = false;
  };
  auto opts = std::make_shared<Opts>();
  sub->add_option("--workload", opts->workload, "paper (49x216x384 tris, 24 views 432x768) | stage1 (17x160x288, 17 "
                                                "views 320x576) | both")
      ->check(CLI::IsMember({"paper", "stage1", "both"}));
  cli::add_device(*sub, opts->device);
  sub->add_option("--triangles", opts->ply, "time this triangle soup PLY instead (with --cameras)");
  sub->add_option("--cameras", opts->cams, "cameras JSON for --triangles");
  sub->add_option("--window", opts->window, "flat | ts")->check(CLI::IsMember({"flat", "ts"}));
  sub->add_option("--repeats", opts->repeats, "timed repeats after 2 warm-ups")->check(CLI::Range(1, 1000));
  sub->add_flag("--profile", opts->profile, "also print GPU time per kernel of one forward+backward step");
  sub->callback([opts] {
    const torch::Device dev = cli::resolve_device(opts->device);
    FLAT_CHECK(!opts->profile || dev.is_cuda(), "flat_bench raster: --profile needs --device cuda (GPU kernel times)");
    render::RasterSettings settings;
    settings.window = opts->window;
    std::printf("| workload | triangles | views | HxW | window | forward ms | fwd+bwd ms | peak GiB |\n|---|---|---|---|---|---|---|---|\n");
    if (!opts->ply.empty()) {
      FLAT_CHECK(!opts->cams.empty(), "flat_bench raster: --triangles needs --cameras");
      const auto soup = exporter::read_triangle_ply(opts->ply);
      const auto set = camera::read_cameras_json(opts->cams);
      Scene sc{soup.vertices.to(dev), soup.colors.to(dev), soup.opacities.to(dev), soup.sigmas.to(dev),
               set.cameras.to(dev), set.height, set.width};
      time_scene(opts->ply, sc, settings, opts->repeats);
      return;
    }
    auto run = [&](const std::string& label, const Scene& sc) {
      time_scene(label, sc, settings, opts->repeats);
      if (opts->profile) profile_scene(label, sc, settings);
    };
    if (opts->workload == "stage1" || opts->workload == "both") run("stage1", room_scene(17, 320, 576, 17, dev));
    if (opts->workload == "paper" || opts->workload == "both") run("paper", room_scene(49, 432, 768, 24, dev));
  });
}

}  // namespace flat::bench
