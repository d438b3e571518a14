// The benchmark behind flat_bench loader: training-loader throughput at a stage's sizes (default
// stage 1: 17 input frames, 17 targets, 320p = 176x320), on synthetic scenes
// written to a temporary folder (or --data DIR), from frame files (PNG/EXR)
// and from packed scenes (frames.safetensors).
//
//   flat_bench loader                                   # stage 1, files and packed
//   flat_bench loader --window 49 --targets 49 --scene-frames 81   # stage 2
//   flat_bench loader --data /data/re10k --workers 8
//
// Reports batches/s and samples/s over --batches batches after --warmup.
#include "flat/bench/loader_benchmark.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>

#include <unistd.h>

#include <spdlog/spdlog.h>

#include "flat/core/cli.h"
#include "flat/core/error.h"
#include "flat/data/loader.h"
#include "flat/data/pack.h"
#include "flat/data/synthetic_scene.h"

namespace flat::bench {
namespace {


std::pair<int64_t, int64_t> parse_size(const std::string& s) {
  long long h = 0, w = 0;
  char x = 0;
  if (std::sscanf(s.c_str(), "%lld%c%lld", &h, &x, &w) != 3 || (x != 'x' && x != 'X'))
    fail("size must be HxW, got '" + s + "'");
  return {h, w};
}

// Deletes a folder tree file by file (std::filesystem::remove_all resolves to
// libtorch's bundled copy, which crashes on non-empty folders).
void remove_tree(const std::filesystem::path& root) {
  std::vector<std::filesystem::path> paths;
  for (const auto& e : std::filesystem::recursive_directory_iterator(root)) paths.push_back(e.path());
  std::sort(paths.begin(), paths.end(), [](const auto& a, const auto& b) { return a.string().size() > b.string().size(); });
  for (const auto& p : paths) std::filesystem::remove(p);
  std::filesystem::remove(root);
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

void time_loader(const LoaderBenchOptions& o, const std::string& root, const std::string& label) {
  data::LoaderConfig c;
  c.datasets = {{root, 1.0}};
  std::tie(c.height, c.width) = parse_size(o.size);
  c.input_frames = o.frames;
  c.target_views = o.targets;
  c.batch_size = o.batch;
  c.workers = o.workers;
  c.prefetch = o.prefetch;
  data::Loader loader(c);
  for (int64_t i = 0; i < o.warmup; ++i) loader.next();
  auto t0 = std::chrono::steady_clock::now();
  double bytes = 0;
  for (int64_t i = 0; i < o.batches; ++i) {
    auto b = loader.next();
    bytes += double(b.target_images.nbytes() + (b.target_depth.defined() ? b.target_depth.nbytes() : 0) +
                    (b.target_normals.defined() ? b.target_normals.nbytes() : 0));
  }
  const double s = seconds_since(t0);
  std::printf("loader %-7s F=%lld V=%lld %lldx%lld batch=%lld workers=%lld: %.2f batches/s, %.2f samples/s, "
              "%.1f target views/s, %.1f MB/s of float tensors\n",
              label.c_str(), (long long)o.frames, (long long)o.targets, (long long)c.height, (long long)c.width,
              (long long)o.batch, (long long)o.workers, double(o.batches) / s, double(o.batches * o.batch) / s,
              double(o.batches * o.batch * o.targets) / s, bytes / s / 1e6);
}

// Bytes of one batch's target frames (RGB, depth, normals as float32): a lower
// bound of what the loader holds, so a refusal never stops a run that fits.
double batch_bytes(const LoaderBenchOptions& o, int64_t height, int64_t width) {
  return double(o.batch) * double(o.targets) * (3 + 1 + 3) * double(height) * double(width) * sizeof(float);
}

// The synthesised dataset is removed on every way out, a failure included.
struct TempTree {
  std::filesystem::path root;
  ~TempTree() {
    std::error_code ec;
    if (root.empty() || !std::filesystem::exists(root, ec)) return;
    try {
      remove_tree(root);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "flat_bench loader: cannot remove the temporary folder %s (%s)\n", root.c_str(), e.what());
    }
  }
};


}  // namespace

void run_loader_benchmark(const LoaderBenchOptions& o) {
  namespace fs = std::filesystem;
  // A missing folder is named as such before anything is said about packing it.
  std::error_code ec;
  if (!o.data.empty() && !fs::is_directory(o.data, ec))
    fail("--data " + o.data + (fs::exists(o.data, ec) ? ": not a folder (a dataset folder holds scene folders)"
                                                       : ": the dataset folder does not exist"));
  if (o.mode != "files" && !o.data.empty())
    fail("--mode packed with --data would pack (modify) your scenes; pack them with flat_pack");
  // A bad --size, or one whose batches cannot fit, is refused before anything is synthesised.
  const auto [height, width] = parse_size(o.size);
  cli::check_memory(batch_bytes(o, height, width),
                    "flat_bench loader: a batch of " + std::to_string(o.batch) + " x " + std::to_string(o.targets) +
                        " target views at " + o.size + " (RGB, depth, normals in float32)",
                    c10::Device(c10::kCPU));
  std::string root = o.data;
  fs::path tmp;
  TempTree temp_tree;
  if (root.empty()) {
    tmp = fs::temp_directory_path() / ("flat_bench_loader_" + std::to_string(::getpid()));
    temp_tree.root = tmp;
    auto [h, w] = parse_size(o.source_size);
    auto t0 = std::chrono::steady_clock::now();
    for (int64_t i = 0; i < o.scenes; ++i) {
      data::SynthOptions s;
      s.family = i % 2 ? "object" : "room";
      s.frames = o.scene_frames;
      s.height = h;
      s.width = w;
      s.seed = uint64_t(i);
      auto scene = data::render_synthetic_scene(s);
      data::write_synthetic_scene(scene, (tmp / ("s" + std::to_string(i))).string(), "s" + std::to_string(i), "bench");
    }
    std::printf("synthesised %lld scenes of %lld frames at %lldx%lld in %.1f s\n", (long long)o.scenes,
                (long long)o.scene_frames, (long long)h, (long long)w, seconds_since(t0));
    root = tmp.string();
  }
  if (o.mode != "packed") time_loader(o, root, "files");
  if (o.mode != "files") {
    for (const auto& e : fs::directory_iterator(root)) {
      auto scene = data::read_scene(e.path().string());
      data::pack_scene(scene, true);
    }
    time_loader(o, root, "packed");
  }
}

}  // namespace flat::bench
