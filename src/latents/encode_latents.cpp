#include "flat/latents/encode_latents.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <random>
#include <set>

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/core/atomic_file.h"
#include "flat/core/cli.h"
#include "flat/core/error.h"
#include "flat/core/progress.h"
#include "flat/core/shape.h"
#include "flat/data/frame_resize.h"
#include "flat/data/scene.h"
#include "flat/data/scene_frames.h"
#include "flat/data/scene_latents.h"
#include "flat/model/camera_latents.h"
#include "flat/model/wan_vae.h"
#include "flat/model/weights.h"

namespace flat::latents {

namespace fs = std::filesystem;

std::string LatentSetSpec::describe() const {
  const std::string size = height ? std::to_string(height) + "x" + std::to_string(width) : "the scenes' size";
  return (height ? data::latent_set_key(height, width, window) : "<scene size>_f" + std::to_string(window)) + " (" +
         std::to_string(window) + "-frame windows at " + size + ")" + (origin.empty() ? "" : " for " + origin);
}

void parse_shard(const std::string& text, int64_t& index, int64_t& count) {
  long long k = -1, n = 0;
  char tail = 0;
  if (std::sscanf(text.c_str(), "%lld/%lld%c", &k, &n, &tail) != 2 || n < 1 || k < 0 || k >= n)
    fail("--shard: expected K/N with 0 <= K < N (e.g. 0/4), got '" + text + "'");
  index = k;
  count = n;
}

namespace {

using Clock = std::chrono::steady_clock;

int64_t window_count(int64_t frames, int64_t window, int64_t step) {
  return frames < window ? 0 : (frames - window) / step + 1;
}

// The frame size a set is encoded at for one scene.
std::pair<int64_t, int64_t> encode_size(const LatentSetSpec& s, const data::Scene& scene) {
  if (s.height) return {s.height, s.width};
  return {scene.height - scene.height % 8, scene.width - scene.width % 8};
}

// The set this run would write into `scene` (windows and provenance; no file yet).
data::LatentInfo planned_set(const LatentSetSpec& s, const data::Scene& scene, const data::LatentInfo& provenance) {
  data::LatentInfo info = provenance;
  std::tie(info.height, info.width) = encode_size(s, scene);
  const int64_t step = s.step > 0 ? s.step : s.window;
  for (int64_t start = 0; start + s.window <= scene.size(); start += step) info.windows.push_back({start, s.window});
  info.plucker = s.plucker;
  return info;
}

bool same_windows(const data::LatentInfo& a, const data::LatentInfo& b) {
  if (a.windows.size() != b.windows.size()) return false;
  for (size_t i = 0; i < a.windows.size(); ++i)
    if (a.windows[i].start != b.windows[i].start || a.windows[i].count != b.windows[i].count) return false;
  return true;
}

// The weights file's content, cheaply: 64-bit FNV-1a over its bytes (a
// retrained VAE keeps its file name; its latents must not pass as present).
// "" for a folder (diffusers layout) or an unreadable file.
std::string file_digest(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return "";
  uint64_t h = 1469598103934665603ull;
  std::vector<char> buf(1 << 20);
  while (in.read(buf.data(), std::streamsize(buf.size())) || in.gcount() > 0) {
    for (std::streamsize i = 0; i < in.gcount(); ++i) h = (h ^ uint8_t(buf[size_t(i)])) * 1099511628211ull;
    if (!in) break;
  }
  char hex[17];
  std::snprintf(hex, sizeof(hex), "%016llx", static_cast<unsigned long long>(h));
  return hex;
}

// "" when the existing set is what this run would make; else how it differs.
std::string difference(const data::LatentInfo& have, const data::LatentInfo& want) {
  if (have.encoder != want.encoder) return "encoder " + have.encoder + " (this run: " + want.encoder + ")";
  if (have.weights != want.weights) return "weights '" + have.weights + "' (this run: '" + want.weights + "')";
  if (!have.weights_digest.empty() && !want.weights_digest.empty() && have.weights_digest != want.weights_digest)
    return "other weights of the same name '" + have.weights + "' (content digest " + have.weights_digest +
           ", this run's " + want.weights_digest + ")";
  if (want.encoder == "random" && have.seed != want.seed)
    return "seed " + std::to_string(have.seed) + " (this run: " + std::to_string(want.seed) + ")";
  if (have.dtype != want.dtype) return "dtype " + have.dtype + " (this run: " + want.dtype + ")";
  if (!same_windows(have, want)) return std::to_string(have.windows.size()) + " windows of another step";
  if (want.plucker && !have.plucker) return "no Plucker camera latents";
  return "";
}

// Every scene folder under the roots, once (by its canonical path, so that two
// spellings of one folder in two sets' roots are one scene), in path order.
std::vector<std::string> scene_folders(const std::vector<std::string>& roots) {
  std::set<std::string> seen;
  for (const auto& root : roots)
    for (const auto& dir : data::scene_dirs_under(root)) {
      std::error_code ec;
      const std::string canonical = fs::weakly_canonical(dir, ec).string();
      seen.insert(ec ? dir : canonical);
    }
  return {seen.begin(), seen.end()};
}

// A fixed-size uniform sample of the scenes' first windows (reservoir sampling,
// seeded): the spread statistic's memory does not grow with the dataset.
class SpreadSample {
 public:
  SpreadSample(int64_t capacity, int64_t seed) : capacity_(capacity), rng_(uint64_t(seed) * 7919 + 17) {}
  void offer(const at::Tensor& latent) {
    if (capacity_ <= 0) return;
    ++offered_;
    if (int64_t(kept_.size()) < capacity_) {
      kept_.push_back(latent);
      return;
    }
    const int64_t j = int64_t(rng_() % uint64_t(offered_));
    if (j < capacity_) kept_[size_t(j)] = latent;
  }
  const std::vector<at::Tensor>& kept() const { return kept_; }

 private:
  int64_t capacity_, offered_ = 0;
  std::mt19937_64 rng_;
  std::vector<at::Tensor> kept_;
};

// One scene's windows of one set, encoded and committed.
struct Encoder {
  model::WanVAE vae{nullptr};
  at::Tensor weight;  // conv2's weight: the device and dtype inputs go to
  bool full = false;

  data::WindowLatents encode_window(const data::Scene& scene, const data::LatentWindow& w, int64_t h, int64_t wd,
                                    bool plucker) {
    std::vector<int64_t> idx(size_t(w.count));
    for (int64_t i = 0; i < w.count; ++i) idx[size_t(i)] = w.start + i;
    data::FrameBatch frames = data::load_frames(scene, idx, false, false);
    auto cams = scene.cameras(idx);
    cams.intrinsics = data::fit_frames(frames, cams.intrinsics, h, wd);  // crop + resize; intrinsics follow
    auto video = (frames.images.permute({1, 0, 2, 3}).unsqueeze(0) * 2 - 1).to(weight.device(), weight.scalar_type());
    data::WindowLatents l;
    l.video = vae->encode(video, !full)[0].to(at::kCPU, at::kFloat);
    l.camera = model::encode_camera_latents(vae, cams.to(weight.device()), h, wd, !full)[0].to(at::kCPU, at::kFloat);
    if (plucker)
      l.camera_plucker = model::encode_camera_latents(vae, cams.to(weight.device()), h, wd, !full, "plucker")[0]
                             .to(at::kCPU, at::kFloat);
    check_finite(l.video, scene.dir + ": window at frame " + std::to_string(w.start) + ": video latent");
    check_finite(l.camera, scene.dir + ": window at frame " + std::to_string(w.start) + ": camera latent");
    return l;
  }
};

Encoder load_encoder(const EncoderSpec& e, int64_t dim, data::LatentInfo& provenance) {
  model::WanVAEConfig config;
  config.dim = dim;
  if (e.random_weights) torch::manual_seed(e.seed);
  Encoder enc;
  enc.vae = model::WanVAE(config);
  enc.full = e.full;
  provenance.seed = e.seed;
  provenance.dtype = cli::stored_dtype_name(e.store);
  if (e.random_weights) {
    provenance.encoder = "random";
    spdlog::warn("=====================================================================");
    spdlog::warn("flat_latents: RANDOM ENCODER WEIGHTS (seed {}, dim {}). These latents are", e.seed, dim);
    spdlog::warn("NOT the Wan 2.1 latents: use them only to test the pipeline. Recorded as");
    spdlog::warn("encoder=\"random\" in the latent files and scene.json.");
    spdlog::warn("=====================================================================");
  } else {
    model::LoadSpec spec;
    spec.strip_prefix = e.weights_prefix;
    auto report = model::load_weights(*enc.vae, e.weights, spec);
    provenance.encoder = "pretrained";
    provenance.weights = fs::path(e.weights).filename().string();
    provenance.weights_digest = fs::is_regular_file(e.weights) ? file_digest(e.weights) : "";
    spdlog::info("flat_latents: PRETRAINED encoder weights from {} (dim {}; {})", e.weights, dim, report.summary());
  }
  enc.vae->eval();
  enc.vae->to(cli::resolve_device(e.device), cli::precision_dtype(e.precision));
  enc.weight = enc.vae->conv2->weight;
  return enc;
}

void write_report(const std::string& file, const EncodeOptions& o, const EncodeSummary& s) {
  using nlohmann::json;
  json j;
  j["sets"] = json::array();
  for (const auto& set : o.sets) j["sets"].push_back(set.describe());
  j["shard"] = std::to_string(o.shard_index) + "/" + std::to_string(o.shard_count);
  j["scenes"] = s.scenes;
  j["encoded"] = s.encoded;
  j["present"] = s.present;
  j["too_short"] = s.too_short;
  j["windows"] = s.windows;
  j["seconds"] = s.seconds;
  // Scenes of this shard handled per minute (encoded, present, short or failed), and sets encoded per minute.
  j["scenes_per_minute"] = Progress::per_minute(s.scenes, s.seconds);
  j["sets_per_minute"] = Progress::per_minute(s.encoded, s.seconds);
  j["failed"] = json::array();
  for (const auto& f : s.failed) j["failed"].push_back({{"scene", f.dir}, {"set", f.set}, {"reason", f.reason}});
  if (s.spread.pairs > 0)
    j["spread"] = {{"scenes", s.spread_scenes},
                   {"pairs", s.spread.pairs},
                   {"mean_correlation", s.spread.mean_correlation},
                   {"min_correlation", s.spread.min_correlation},
                   {"max_correlation", s.spread.max_correlation}};
  write_file_atomic(file, j.dump(2) + "\n");
}

}  // namespace

EncodeSummary encode_latent_sets(const EncodeOptions& o) {
  const auto t0 = Clock::now();
  const auto& e = o.encoder;
  FLAT_CHECK(!o.sets.empty(), "flat_latents: no latent set to make");
  FLAT_CHECK(o.shard_count >= 1 && o.shard_index >= 0 && o.shard_index < o.shard_count,
             "flat_latents: shard " + std::to_string(o.shard_index) + " of " + std::to_string(o.shard_count));
  for (const auto& s : o.sets) {
    FLAT_CHECK(s.window >= 1 && (s.window - 1) % 4 == 0,
               "flat_latents: " + s.describe() + ": a window must be 1+4k frames (17, 49, ...)");
    FLAT_CHECK(s.height % 8 == 0 && s.width % 8 == 0 && (s.height == 0) == (s.width == 0),
               "flat_latents: " + s.describe() + ": the size must be multiples of 8 (the VAE downsamples by 8)");
    FLAT_CHECK(!s.roots.empty(), "flat_latents: " + s.describe() + ": no scene folders");
  }
  const auto device = cli::resolve_device(e.device);
  const int64_t dim = e.random_weights ? (e.dim > 0 ? e.dim : 96) : model::vae_dim_of_file(e.weights);

  // This shard's scenes: every set's folders, each scene once, K, K+N, ... of the sorted list.
  std::vector<std::string> all_roots;
  for (const auto& s : o.sets) all_roots.insert(all_roots.end(), s.roots.begin(), s.roots.end());
  const auto all = scene_folders(all_roots);
  std::map<std::string, std::vector<size_t>> sets_of;  // scene dir -> the sets it is in
  for (size_t k = 0; k < o.sets.size(); ++k)
    for (const auto& dir : scene_folders(o.sets[k].roots)) sets_of[dir].push_back(k);
  std::vector<std::string> dirs;
  for (size_t i = 0; i < all.size(); ++i)
    if (int64_t(i) % o.shard_count == o.shard_index) dirs.push_back(all[i]);

  EncodeSummary sum;
  sum.scenes = int64_t(dirs.size());
  // A first pass over scene.json only (no frames, nothing kept): the windows to
  // encode, for the progress line and the memory check, and what is unreadable.
  int64_t total_windows = 0, largest = 0, longest = 0, max_window = 0;
  for (const auto& dir : dirs) {
    try {
      const data::Scene scene = data::read_scene(dir, /*check_files=*/false);
      longest = std::max(longest, scene.size());
      for (size_t k : sets_of[dir]) {
        const auto& s = o.sets[k];
        const int64_t n = window_count(scene.size(), s.window, s.step > 0 ? s.step : s.window);
        const auto [h, w] = encode_size(s, scene);
        if (n > 0 && (o.overwrite || !data::find_latent_set(scene, h, w, s.window))) {
          total_windows += n;
          largest = std::max(largest, h * w);
          max_window = std::max(max_window, s.window);
        }
      }
    } catch (const std::exception&) {
      // Reported in the second pass, which reads it again.
    }
  }
  spdlog::info("flat_latents: {} scene folders{} for {} set(s): {} windows to encode", dirs.size(),
               o.shard_count > 1 ? " (shard " + std::to_string(o.shard_index) + "/" + std::to_string(o.shard_count) +
                                       " of " + std::to_string(all.size()) + ")"
                                 : "",
               o.sets.size(), total_windows);
  for (const auto& s : o.sets) spdlog::info("flat_latents: set {}", s.describe());

  data::LatentInfo provenance;
  Encoder enc;
  if (total_windows > 0) {
    // A window's frames plus the encoder's widest activations (dim channels at
    // full size, a chunk of 4 frames when streaming): refuse what cannot fit.
    const double in_flight = e.full ? double(max_window) : 4.0;
    cli::check_memory(double(largest) * 4.0 * (3.0 * double(max_window) + 6.0 * double(dim) * in_flight),
                      "flat_latents: encoding a window of " + std::to_string(max_window) + " frames", device);
    enc = load_encoder(e, dim, provenance);
  } else {
    provenance.encoder = e.random_weights ? "random" : "pretrained";
    provenance.weights = e.random_weights ? "" : fs::path(e.weights).filename().string();
    provenance.weights_digest =
        !e.random_weights && fs::is_regular_file(e.weights) ? file_digest(e.weights) : "";
    provenance.seed = e.seed;
    provenance.dtype = cli::stored_dtype_name(e.store);
  }
  sum.longest = longest;
  torch::NoGradGuard no_grad;

  SpreadSample spread(o.spread_sample, e.seed);
  std::optional<Progress> progress;  // only when there is something to encode
  if (total_windows > 0) progress.emplace("flat_latents windows", total_windows, 5.0);
  int64_t attempted = 0;
  for (const auto& dir : dirs) {
    data::Scene scene;
    try {
      scene = data::read_scene(dir);
      if (const int stale = data::remove_stale_staged_latents(scene))
        spdlog::warn("{}: removed {} staged latent file(s) that a killed run left", scene.dir, stale);
    } catch (const std::exception& ex) {
      sum.failed.push_back({dir, "", ex.what()});
      spdlog::warn("flat_latents: {}: skipped: {}", dir, ex.what());
      continue;
    }
    for (size_t k : sets_of[dir]) {
      const auto& s = o.sets[k];
      const data::LatentInfo want = planned_set(s, scene, provenance);
      const std::string key = data::latent_set_key(want);
      if (want.windows.empty()) {
        ++sum.too_short;
        spdlog::info("flat_latents: {}: {} frames, fewer than one window of {}; no set {}", dir, scene.size(), s.window,
                     key);
        continue;
      }
      if (const auto* have = data::find_latent_set(scene, want.height, want.width, want.frames())) {
        const std::string diff = difference(*have, want);
        if (diff.empty() && !o.overwrite) {
          ++sum.present;
          continue;
        }
        if (!diff.empty() && !o.overwrite) {
          sum.failed.push_back({dir, key, "already holds set " + key + " made with " + diff +
                                              "; --overwrite replaces it"});
          spdlog::warn("flat_latents: {}: set {} exists with {}; left as it is (--overwrite replaces it)", dir, key,
                       diff);
          continue;
        }
      }
      ++attempted;
      data::StagedLatents staged;
      try {
        std::vector<data::WindowLatents> latents;
        for (const auto& w : want.windows) {
          latents.push_back(enc.encode_window(scene, w, want.height, want.width, s.plucker));
          if (progress) progress->step();
        }
        if (k == sets_of[dir].front()) spread.offer(latents.front().video);
        staged = data::stage_scene_latents(scene, want, latents);
        data::commit_scene_latents(scene, staged);
        staged = {};
        ++sum.encoded;
        sum.windows += int64_t(latents.size());
      } catch (const std::exception& ex) {
        if (!staged.path.empty()) data::discard_staged_latents(staged);
        sum.failed.push_back({dir, key, ex.what()});
        spdlog::warn("flat_latents: {}: set {} failed: {}", dir, key, ex.what());
        // The same error on every scene is the run's, not the data's: stop early.
        if (sum.encoded == 0 && int64_t(sum.failed.size()) >= 8 && attempted == int64_t(sum.failed.size()))
          fail("flat_latents: the first " + std::to_string(attempted) + " scenes all failed; stopping (the last: " +
               ex.what() + ")");
      }
    }
  }
  if (progress) progress->finish();
  sum.spread_scenes = int64_t(spread.kept().size());
  sum.spread = eval::latent_spread(spread.kept());
  sum.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  if (!o.report_file.empty()) write_report(o.report_file, o, sum);
  return sum;
}

}  // namespace flat::latents
