// The benchmark behind flat_bench raster: forward and forward+backward time (median) and peak GPU
// memory of the triangle rasterizer, with each view's load (visible
// triangles, tile pairs, list entries per pixel) beside the times.
// Workloads (flat/bench/raster_workload.h): anchor-large and anchor-small, the
// benchmark of record (the triangles ../shared/bench/raster_workload.py gives
// the public Triangle Splatting rasterizer); paper and stage1, our older room
// scenes; or any PLY + cameras JSON. --device auto|cpu|cuda (peak memory and
// load are reported on CUDA only).
#include "flat/bench/raster_benchmark.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <map>

#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDACachingAllocator.h>
#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/bench/gpu_profile.h"
#include "flat/bench/raster_workload.h"
#include "flat/bench/timing.h"
#include "flat/camera/camera_json.h"
#include "flat/core/cli.h"
#include "flat/core/device_memory.h"
#include "flat/core/error.h"
#include "flat/export/triangle_ply.h"
#include "flat/pipeline/scene_pipeline.h"
#include "flat/primitives/scene_primitives.h"
#include "flat/primitives/triangle_gaussians.h"
#include "flat/render/raster_load.h"
#include "flat/render/rasterize.h"

namespace flat::bench {
namespace {

// Where the GPU idles in the step: time with no kernel, copy or memset
// running on any stream, split at the end of the forward (the last
// forward compositing kernel), and which activity each idle gap precedes (a gap
// before a kernel is time the GPU waited for the host to launch it). Gaps
// are grouped by the activities before and after them.
void print_gpu_idle(std::vector<GpuActivity> spans) {
  if (spans.empty()) return;
  int64_t fwd_end = spans.front().start_ns;
  for (const auto& s : spans)
    if (s.name.find("raster_forward_kernel") != std::string::npos) fwd_end = std::max(fwd_end, s.end_ns);
  double idle[2] = {0, 0};
  std::map<std::string, std::pair<double, int>> before;  // next activity -> (idle ms, gaps)
  int64_t busy_until = spans.front().end_ns;
  std::string last_name = spans.front().name;  // the activity that ends last so far
  for (size_t i = 1; i < spans.size(); ++i) {
    const GpuActivity& s = spans[i];
    if (s.start_ns > busy_until) {
      const double gap = (s.start_ns - busy_until) * 1e-6;
      idle[s.start_ns > fwd_end ? 1 : 0] += gap;
      auto& b = before[(s.start_ns > fwd_end ? "bwd " : "fwd ") + short_kernel_name(last_name) + " > " + short_kernel_name(s.name)];
      b.first += gap;
      b.second += 1;
    }
    if (s.end_ns > busy_until) last_name = s.name;
    busy_until = std::max(busy_until, s.end_ns);
  }
  const double span_ms = (busy_until - spans.front().start_ns) * 1e-6, fwd_ms = (fwd_end - spans.front().start_ns) * 1e-6;
  std::printf("GPU timeline: first to last activity %.2f ms (forward %.2f ms), idle %.2f ms in the forward and "
              "%.2f ms after it; idle before:\n",
              span_ms, fwd_ms, idle[0], idle[1]);
  std::vector<std::pair<double, std::string>> rows;
  for (const auto& [name, b] : before) rows.push_back({b.first, name + " x" + std::to_string(b.second)});
  std::sort(rows.rbegin(), rows.rend());
  for (size_t i = 0; i < rows.size() && i < 12; ++i) std::printf("  %8.3f  %s\n", rows[i].first, rows[i].second.c_str());
}

// Mean and maximum over views of the load counts (one forward).
struct LoadSummary {
  double visible = 0, pairs = 0, entries = 0;
  double blended = 0;  // triangles with a blended fragment in the view (max_weight > 0 of that view alone)
  int64_t visible_max = 0, pairs_max = 0;
  double entries_max = 0;
};

LoadSummary summarise_load(const RasterWorkload& sc, const render::RasterSettings& settings) {
  const auto load = render::measure_raster_load(sc.vertices, sc.colors, sc.opacities, sc.sigmas, sc.targets, sc.height,
                                                sc.width, settings);
  LoadSummary s;
  for (const auto& l : load) {
    s.visible += double(l.visible) / double(load.size());
    s.pairs += double(l.tile_pairs) / double(load.size());
    s.entries += l.entries_mean / double(load.size());
    s.visible_max = std::max(s.visible_max, l.visible);
    s.pairs_max = std::max(s.pairs_max, l.tile_pairs);
    s.entries_max = std::max(s.entries_max, l.entries_mean);
  }
  // One view at a time: the triangles that blend somewhere in that view (the
  // rest of the visible ones receive no gradient from it).
  torch::NoGradGuard ng;
  const int64_t V = sc.targets.size();
  for (int64_t v = 0; v < V; ++v) {
    const auto one = sc.targets.index(torch::tensor({v}));
    const auto r = render::rasterize(sc.vertices, sc.colors, sc.opacities, sc.sigmas, one, sc.height, sc.width,
                                     settings);
    s.blended += double((r.max_weight > 0).sum().item<int64_t>()) / double(V);
  }
  return s;
}

// The workload's triangles, or the Gaussians made from them (same count,
// positions and footprint: primitives/triangle_gaussians.h).
primitives::ScenePrimitives workload_primitives(const RasterWorkload& sc, const std::string& representation) {
  primitives::TriangleSoup t{sc.vertices, sc.colors, sc.opacities, sc.sigmas};
  if (representation == primitives::kTriangles) return primitives::ScenePrimitives::of(t);
  return primitives::ScenePrimitives::of(
      primitives::gaussians_from_triangles(t, representation == primitives::kGaussians3d ? 3 : 2));
}

// One forward+backward step of `representation` under the libtorch (Kineto)
// profiler: GPU time per kernel name, summed over the step (where the time
// goes, without nsys), and where the GPU idles.
void profile_scene(const RasterWorkload& sc, const render::RasterSettings& settings,
                   const std::string& representation) {
  const auto leaves = workload_primitives(sc, representation).map([](const at::Tensor& x) {
    return x.detach().requires_grad_(true);
  });
  double t0 = 0, t_fwd_host = 0, t_bwd_host = 0;
  const auto spans = record_gpu_activities([&] {
    t0 = now_ms();
    auto r = pipeline::rasterize_scene(leaves, sc.targets, sc.height, sc.width, settings);
    t_fwd_host = now_ms();
    auto loss = r.rgb.sum() + r.alpha.sum() + r.depth.sum();
    if (r.normal.defined()) loss = loss + r.normal.sum();  // 3DGS renders no normal
    loss.backward();
    t_bwd_host = now_ms();
  });
  const double t_end = now_ms();
  std::printf("profile %s %s: host returned from the forward after %.2f ms, from the backward call after %.2f ms, "
              "GPU done after %.2f ms (with the profiler's overhead)\n",
              sc.name.c_str(), representation.c_str(), t_fwd_host - t0, t_bwd_host - t0, t_end - t0);
  print_gpu_idle(spans);
  print_grouped("profile " + sc.name + " " + representation + " (one fwd+bwd step, per kernel)", spans, 14,
                [](const std::string& n) { return n.substr(0, 60); });
}

void time_scene(const RasterWorkload& sc, const render::RasterSettings& settings, int repeats,
                const std::string& representation) {
  const auto dev = sc.vertices.device();
  const auto scene = workload_primitives(sc, representation);
  const bool triangles = scene.is_triangles();
  const std::string what = triangles ? "triangles" : representation + " Gaussians";
  auto sync = [&] { sync_device(dev); };
  const int64_t V = sc.targets.size();
  // Random upstream weights so every output carries gradient.
  auto w_rgb = torch::rand({V, 3, sc.height, sc.width}, sc.vertices.options());
  std::vector<double> fwd, fwdbwd, fwd_host;  // fwd_host: until the forward call returns
  double peak_fwd = 0, peak_all = 0;
  int64_t contributing = 0;
  // Said before the first run, and after each run slower than 2 s: on the CPU
  // the paper's workload takes minutes, and must not be silent.
  spdlog::info("raster {}: {} {}, {} views at {}x{} on {}: 2 warm-up + {} timed forward+backward run(s)", sc.name,
               scene.size(), what, V, sc.height, sc.width, dev.is_cuda() ? "cuda" : "cpu", repeats);
  for (int it = 0; it < repeats + 2; ++it) {
    const double t_run = now_ms();
    {
      torch::NoGradGuard ng;
      sync();
      reset_peak_memory(dev);
      const double t0 = now_ms();
      auto r = pipeline::rasterize_scene(scene, sc.targets, sc.height, sc.width, settings);
      const double t_host = now_ms();
      sync();
      const double t1 = now_ms();
      if (it >= 2) fwd.push_back(t1 - t0);
      if (it >= 2) fwd_host.push_back(t_host - t0);
      peak_fwd = std::max(peak_fwd, peak_memory_gib(dev));
      if (it == 0) contributing = (r.max_weight > 0).sum().item<int64_t>();
    }
    const auto leaves = scene.map([](const at::Tensor& x) { return x.detach().requires_grad_(true); });
    sync();
    reset_peak_memory(dev);
    const double t0 = now_ms();
    auto r = pipeline::rasterize_scene(leaves, sc.targets, sc.height, sc.width, settings);
    auto loss = (r.rgb * w_rgb).sum() + r.alpha.sum() + 0.1 * r.depth.sum();
    if (r.normal.defined()) loss = loss + r.normal.sum();  // 3DGS renders no normal
    if (r.distortion.defined()) loss = loss + r.distortion.sum();
    loss.backward();
    sync();
    const double t1 = now_ms();
    if (it >= 2) fwdbwd.push_back(t1 - t0);
    peak_all = std::max(peak_all, peak_memory_gib(dev));
    const double run_ms = now_ms() - t_run;
    if (run_ms >= 2000 && it + 1 < repeats + 2)
      spdlog::info("  run {} of {} took {:.1f} s; about {:.0f} s to go for {}", it + 1, repeats + 2, run_ms / 1000,
                   run_ms / 1000 * (repeats + 1 - it), sc.name);
  }
  spdlog::info("raster {}: {} {} ({} blended somewhere), {} views at {}x{}{}", sc.name, scene.size(), what,
               contributing, V, sc.height, sc.width, triangles ? ", window " + settings.window : "");
  std::string load_cells = "- | - | -";
  if (dev.is_cuda() && triangles) {
    const LoadSummary l = summarise_load(sc, settings);
    spdlog::info("raster {}: per view, mean (max): {:.3f} M ({:.3f} M) visible triangles ({:.3f} M blended), "
                 "{:.3f} M ({:.3f} M) triangle-tile pairs, {:.0f} ({:.0f}) list entries per pixel",
                 sc.name, l.visible * 1e-6, l.visible_max * 1e-6, l.blended * 1e-6, l.pairs * 1e-6,
                 l.pairs_max * 1e-6, l.entries, l.entries_max);
    load_cells = fmt::format("{:.2f} M | {:.2f} M | {:.0f}", l.visible * 1e-6, l.pairs * 1e-6, l.entries);
  }
  spdlog::info("raster {}: forward {:.2f} ms (median of {}; the host call returns after {:.2f} ms), forward+backward "
               "{:.2f} ms, peak {:.2f} GiB forward, {:.2f} GiB forward+backward",
               sc.name, median(fwd), repeats, median(fwd_host), median(fwdbwd), peak_fwd, peak_all);
  std::printf("| %s | %s | %lld | %lld | %lldx%lld | %s | %s | %.2f | %.2f | %.2f |\n", sc.name.c_str(),
              representation.c_str(), (long long)scene.size(), (long long)V, (long long)sc.height, (long long)sc.width,
              triangles ? settings.window.c_str() : "-", load_cells.c_str(), median(fwd), median(fwdbwd), peak_all);
  std::fflush(stdout);
}

// The workload as a triangle PLY and a cameras JSON (the layout of
// ../shared/bench/export_workload.py), for comparison with its files.
void write_workload(const RasterWorkload& sc, const std::string& dir) {
  std::filesystem::create_directories(dir);
  primitives::TriangleSoup soup;
  soup.vertices = sc.vertices.cpu();
  soup.colors = sc.colors.cpu();
  soup.opacities = sc.opacities.cpu();
  soup.sigmas = sc.sigmas.cpu();
  const std::string stem = dir + "/" + sc.name;
  exporter::write_triangle_ply(stem + ".ply", soup);
  camera::write_cameras_json(stem + "_cameras.json", {sc.targets.to(torch::kCPU), sc.width, sc.height});
  spdlog::info("raster {}: wrote {}.ply and {}_cameras.json", sc.name, stem, stem);
}

}  // namespace

void run_raster_benchmark(const RasterBenchOptions& o) {
  const torch::Device dev = cli::resolve_device(o.device);
  FLAT_CHECK(!o.profile || dev.is_cuda(), "flat_bench raster: --profile needs --device cuda (GPU kernel times)");
  render::RasterSettings settings;
  settings.window = o.window;
  settings.views_per_bin = o.views_per_bin;
  std::printf("| workload | primitives | count | views | HxW | window | visible / view | pairs / view | "
              "entries / px | forward ms | fwd+bwd ms | peak GiB |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  auto run = [&](const RasterWorkload& sc) {
    if (!o.write_dir.empty()) write_workload(sc, o.write_dir);
    for (const auto& rep : o.representations) {
      time_scene(sc, settings, o.repeats, rep);
      if (o.profile) profile_scene(sc, settings, rep);
    }
  };
  if (!o.ply.empty()) {
    FLAT_CHECK(!o.cams.empty(), "flat_bench raster: --triangles needs --cameras");
    const auto soup = exporter::read_triangle_ply(o.ply);
    const auto set = camera::read_cameras_json(o.cams);
    run(RasterWorkload{o.ply, soup.vertices.to(dev), soup.colors.to(dev), soup.opacities.to(dev),
                       soup.sigmas.to(dev), set.cameras.to(dev), set.height, set.width});
    return;
  }
  for (const auto& w : o.workloads) {
    if (w == "anchor-large") run(anchor_workload("large", dev, o.seed));
    if (w == "anchor-small") run(anchor_workload("small", dev, o.seed));
    if (w == "paper") run(room_workload("paper", 49, 432, 768, 24, dev));
    if (w == "stage1") run(room_workload("stage1", 17, 320, 576, 17, dev));
  }
}

}  // namespace flat::bench
