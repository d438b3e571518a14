#include "flat/data/loader.h"

#include <algorithm>
#include <filesystem>

#include <ATen/Parallel.h>
#include <spdlog/spdlog.h>

#include "flat/core/error.h"
#include "flat/data/frame_resize.h"
#include "flat/data/scene_frames.h"
#include "flat/data/scene_latents.h"

namespace flat::data {

namespace fs = std::filesystem;

void LoaderConfig::check() const {
  FLAT_CHECK(!datasets.empty(), "loader: 'datasets' is empty");
  double total = 0;
  for (const auto& d : datasets) total += d.weight;
  FLAT_CHECK(total > 0, "loader: every dataset has weight 0");
  FLAT_CHECK((input_frames - 1) % 4 == 0, "loader: 'input_frames' must be 1+4k (the VAE's temporal stride), got " +
                                              std::to_string(input_frames));
}

ViewSamplerConfig LoaderConfig::views() const {
  return {input_frames, target_views, unseen_fraction, frame_stride, unseen_max_gap};
}

namespace {

// Scene folders under a dataset root: the root itself if it holds scene.json,
// else its sub-folders in name order.
std::vector<std::string> scene_dirs(const std::string& root) {
  if (!fs::is_directory(root)) fail("loader: dataset folder '" + root + "' does not exist");
  if (fs::exists(fs::path(root) / kSceneFile)) return {root};
  std::vector<std::string> dirs;
  for (const auto& e : fs::directory_iterator(root))
    if (e.is_directory()) dirs.push_back(e.path().string());
  std::sort(dirs.begin(), dirs.end());
  return dirs;
}

// Frames a scene needs: one latent window (its frames are the window), else one sampled window.
int64_t frames_needed(const LoaderConfig& c) { return c.latents ? c.input_frames : window_span(c.views()); }

// "17+ frames, latent set 176x320_f17 (17-frame windows at 176x320)"
std::string stage_needs(const LoaderConfig& c) {
  return std::to_string(frames_needed(c)) + "+ frames" +
         (c.latents ? ", latent set " + latent_set_key(c.height, c.width, c.input_frames) + " (" +
                          std::to_string(c.input_frames) + "-frame windows at " + std::to_string(c.height) + "x" +
                          std::to_string(c.width) + ")"
                    : "");
}

void log_dataset_report(const DatasetReport& r, const LoaderConfig& c) {
  spdlog::info("loader: dataset '{}' (weight {}): {} of {} scenes used, {} with depth, {} with normals", r.root,
               r.weight, r.used, r.found, r.with_depth, r.with_normals);
  if (r.short_scenes)
    spdlog::info("loader: dataset '{}': {} scenes left out: fewer than the {} frames one window of this stage spans",
                 r.root, r.short_scenes, frames_needed(c));
  if (r.missing_set) {
    std::string held;
    for (const auto& [sets, n] : r.other_sets) held += (held.empty() ? "" : "; ") + std::to_string(n) + " hold " + sets;
    spdlog::warn("loader: dataset '{}': {} scenes left out: no latent set {} (this stage's {}-frame windows at {}x{}); "
                 "{} (e.g. {}; flat_latents --size {}x{} --window {} makes it)",
                 r.root, r.missing_set, latent_set_key(c.height, c.width, c.input_frames), c.input_frames, c.height,
                 c.width, held, r.example_missing, c.height, c.width, c.input_frames);
  }
  if (r.bad) spdlog::warn("loader: dataset '{}': {} scenes left out: unreadable (skip_bad_scenes)", r.root, r.bad);
}

// A mixture that silently loses a dataset trains on another distribution: with
// incomplete_datasets: fail that stops the run, naming every dataset at fault.
void check_dataset_reports(const std::vector<DatasetReport>& reports, const LoaderConfig& c) {
  std::string lost;
  for (const auto& r : reports) {
    if (r.weight > 0 && r.used == 0)
      lost += "\n  dataset '" + r.root + "' (weight " + std::to_string(r.weight) + "): no usable scene of " +
              std::to_string(r.found) + " (" + std::to_string(r.short_scenes) + " too short, " +
              std::to_string(r.missing_set) + " without the latent set, " + std::to_string(r.bad) + " unreadable)";
    else if (r.missing_set && c.incomplete_datasets == "fail")
      lost += "\n  dataset '" + r.root + "': " + std::to_string(r.missing_set) + " of " + std::to_string(r.found) +
              " scenes lack the latent set (e.g. " + r.example_missing + ")";
  }
  if (lost.empty()) return;
  const std::string what = "loader: the stage needs " + stage_needs(c) + ":" + lost;
  if (c.incomplete_datasets == "fail")
    fail(what + "\n(data.incomplete_datasets: fail; flat_latents --size " + std::to_string(c.height) + "x" +
         std::to_string(c.width) + " --window " + std::to_string(c.input_frames) +
         " makes the set, or set data.incomplete_datasets: warn to train on what is there)");
  spdlog::warn("{}\nThe mixture changes: the other datasets' weights are renormalised "
               "(data.incomplete_datasets: fail stops instead)", what);
}

std::mt19937_64 sample_rng(int64_t seed, int64_t index, int64_t attempt) {
  std::seed_seq seq{uint32_t(uint64_t(seed)), uint32_t(uint64_t(seed) >> 32), uint32_t(uint64_t(index)),
                    uint32_t(uint64_t(index) >> 32), uint32_t(attempt)};
  return std::mt19937_64(seq);
}

at::Tensor stack_or_undefined(const std::vector<at::Tensor>& ts) {
  for (const auto& t : ts)
    if (!t.defined()) return {};
  return at::stack(ts);
}

}  // namespace

Loader::Loader(LoaderConfig config, int64_t start_batch, int64_t rank, int64_t world_size)
    : config_(std::move(config)), rank_(rank), world_size_(world_size) {
  config_.check();
  FLAT_CHECK(world_size >= 1 && rank >= 0 && rank < world_size,
             "loader: rank " + std::to_string(rank) + " of world size " + std::to_string(world_size) + " is invalid");
  FLAT_CHECK(start_batch >= 0, "loader: start batch " + std::to_string(start_batch) + " is negative");
  next_claim_ = next_give_ = start_batch;
  for (const auto& src : config_.datasets) {
    Dataset d;
    d.root = src.root;
    d.weight = src.weight;
    DatasetReport r;
    r.root = src.root;
    r.weight = src.weight;
    for (const auto& dir : scene_dirs(src.root)) {
      ++r.found;
      std::shared_ptr<Scene> scene;
      try {
        scene = std::make_shared<Scene>(read_scene(dir, true));
      } catch (const Error& e) {
        if (!config_.skip_bad_scenes) throw;
        mark_bad(dir, e.what());
        ++r.bad;
        continue;
      }
      // Scenes that cannot give a sample of this stage are left out and counted by reason.
      if (scene->size() < frames_needed(config_)) {
        ++r.short_scenes;
        continue;
      }
      if (config_.latents) {
        // The set of this stage's size and window; the scene's other sets are not read.
        if (!find_latent_set(*scene, config_.height, config_.width, config_.input_frames)) {
          ++r.missing_set;
          ++r.other_sets[latent_set_list(*scene)];
          if (r.example_missing.empty()) r.example_missing = dir;
          continue;
        }
        select_latent_set(*scene, config_.height, config_.width, config_.input_frames);
      }
      r.with_depth += scene->has_depth;
      r.with_normals += scene->has_normals;
      d.scenes.push_back(scene);
    }
    r.used = int64_t(d.scenes.size());
    log_dataset_report(r, config_);
    reports_.push_back(r);
    datasets_.push_back(std::move(d));
  }
  check_dataset_reports(reports_, config_);
  double total = 0;
  for (const auto& d : datasets_) total += d.scenes.empty() ? 0 : d.weight;
  if (total <= 0)
    fail("loader: no usable scenes in any dataset with a positive weight (the stage asks for " +
         stage_needs(config_) + "; see the per-dataset lines above)");
  double acc = 0;
  for (const auto& d : datasets_) {
    acc += d.scenes.empty() ? 0 : d.weight / total;
    cumulative_.push_back(acc);
  }
}

Loader::~Loader() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  space_cv_.notify_all();
  ready_cv_.notify_all();
  for (auto& t : threads_) t.join();
}

int64_t Loader::scenes_with_depth() const {
  int64_t n = 0;
  for (const auto& r : reports_) n += r.with_depth;
  return n;
}

int64_t Loader::scenes_with_normals() const {
  int64_t n = 0;
  for (const auto& r : reports_) n += r.with_normals;
  return n;
}

int64_t Loader::scene_count() const {
  int64_t n = 0;
  for (const auto& d : datasets_) n += int64_t(d.scenes.size());
  return n;
}

std::map<std::string, int64_t> Loader::latent_encoders() const {
  std::map<std::string, int64_t> n;
  for (const auto& d : datasets_)
    for (const auto& scene : d.scenes) ++n[scene->latents.present() ? scene->latents.encoder : "none"];
  return n;
}

void Loader::mark_bad(const std::string& dir, const std::string& why) {
  std::lock_guard<std::mutex> lock(bad_mutex_);
  if (!bad_.insert(dir).second) return;
  ++skipped_;
  spdlog::warn("loader: skipping bad scene '{}' ({} skipped so far): {}", dir, skipped_.load(), why);
}

bool Loader::is_bad(const std::string& dir) {
  std::lock_guard<std::mutex> lock(bad_mutex_);
  return bad_.count(dir) > 0;
}

Sample Loader::load_sample(const Scene& scene, std::mt19937_64& rng) const {
  const auto& c = config_;
  ViewSample v = sample_views(scene.size(), c.views(), rng, c.latents ? &scene.latents.windows : nullptr);
  Sample s;
  s.scene = scene.name;
  s.scene_dir = scene.dir;
  s.input_frames = v.input;
  s.target_frames = v.targets;
  s.target_seen = at::empty({int64_t(v.seen.size())}, at::kBool);
  for (size_t i = 0; i < v.seen.size(); ++i) s.target_seen[int64_t(i)] = bool(v.seen[i]);

  const Crop crop = aspect_crop(scene.height, scene.width, c.height, c.width);
  auto in_cams = scene.cameras(v.input);
  s.input_cameras = {crop_intrinsics(in_cams.intrinsics, scene.height, scene.width, crop), in_cams.c2w};
  auto tg_cams = scene.cameras(v.targets);
  FrameBatch targets = load_frames(scene, v.targets, c.depth && scene.has_depth, c.normals && scene.has_normals);
  s.target_cameras = {fit_frames(targets, tg_cams.intrinsics, c.height, c.width), tg_cams.c2w};
  s.target_images = targets.images;
  s.target_depth = targets.depth;
  s.target_normals = targets.normals;
  if (c.input_images) {
    FrameBatch inputs = load_frames(scene, v.input, false, false);
    fit_frames(inputs, in_cams.intrinsics, c.height, c.width);
    s.input_images = inputs.images;
  }
  if (c.latents) {
    WindowLatents l = read_window_latents(scene, size_t(v.latent_window), c.camera_rays);
    s.video_latent = l.video;
    s.camera_latent = l.camera;
  }
  return s;
}

Sample Loader::sample(int64_t index) {
  for (int64_t attempt = 0; attempt < 1000; ++attempt) {
    auto rng = sample_rng(config_.seed, index, attempt);
    const double u = double(rng() >> 11) * 0x1.0p-53;
    size_t d = size_t(std::upper_bound(cumulative_.begin(), cumulative_.end(), u) - cumulative_.begin());
    d = std::min(d, datasets_.size() - 1);
    while (datasets_[d].scenes.empty()) d = (d + 1) % datasets_.size();
    const auto& scenes = datasets_[d].scenes;
    const Scene& scene = *scenes[size_t(rng() % scenes.size())];
    if (is_bad(scene.dir)) continue;
    try {
      return load_sample(scene, rng);
    } catch (const std::exception& e) {
      const std::string why = e.what();
      if (!config_.skip_bad_scenes) fail("loader: scene '" + scene.name + "' (" + scene.dir + "): " + why);
      mark_bad(scene.dir, why);
    }
  }
  fail("loader: no good scene found in 1000 attempts (" + std::to_string(skipped_.load()) + " bad scenes)");
}

Batch collate(const std::vector<Sample>& samples) {
  FLAT_CHECK(!samples.empty(), "collate: no samples");
  Batch b;
  std::vector<at::Tensor> inf, tgf, seen, ik, ic, tk, tc, ii, ti, td, tn, vl, cl;
  std::vector<bool> dp, np;
  const auto& ref = samples[0].target_images;
  for (const auto& s : samples) {
    b.scenes.push_back(s.scene);
    inf.push_back(at::tensor(s.input_frames, at::kLong));
    tgf.push_back(at::tensor(s.target_frames, at::kLong));
    seen.push_back(s.target_seen);
    ik.push_back(s.input_cameras.intrinsics);
    ic.push_back(s.input_cameras.c2w);
    tk.push_back(s.target_cameras.intrinsics);
    tc.push_back(s.target_cameras.c2w);
    ii.push_back(s.input_images);
    ti.push_back(s.target_images);
    const auto V = ref.size(0), H = ref.size(2), W = ref.size(3);
    dp.push_back(s.target_depth.defined());
    np.push_back(s.target_normals.defined());
    td.push_back(s.target_depth.defined() ? s.target_depth : at::zeros({V, 1, H, W}));
    tn.push_back(s.target_normals.defined() ? s.target_normals : at::zeros({V, 3, H, W}));
    vl.push_back(s.video_latent);
    cl.push_back(s.camera_latent);
  }
  b.input_frames = at::stack(inf);
  b.target_frames = at::stack(tgf);
  b.target_seen = at::stack(seen);
  b.input_intrinsics = at::stack(ik);
  b.input_c2w = at::stack(ic);
  b.target_intrinsics = at::stack(tk);
  b.target_c2w = at::stack(tc);
  b.input_images = stack_or_undefined(ii);
  b.target_images = at::stack(ti);
  b.depth_present = at::empty({int64_t(samples.size())}, at::kBool);
  b.normals_present = at::empty({int64_t(samples.size())}, at::kBool);
  for (size_t i = 0; i < samples.size(); ++i) {
    b.depth_present[int64_t(i)] = bool(dp[i]);
    b.normals_present[int64_t(i)] = bool(np[i]);
  }
  if (std::find(dp.begin(), dp.end(), true) != dp.end()) b.target_depth = at::stack(td);
  if (std::find(np.begin(), np.end(), true) != np.end()) b.target_normals = at::stack(tn);
  b.video_latents = stack_or_undefined(vl);
  b.camera_latents = stack_or_undefined(cl);
  return b;
}

Batch Loader::batch(int64_t index) {
  std::vector<Sample> samples;
  const int64_t first = (index * world_size_ + rank_) * config_.batch_size;
  for (int64_t i = 0; i < config_.batch_size; ++i) samples.push_back(sample(first + i));
  return collate(samples);
}

void Loader::worker() {
  for (;;) {
    int64_t index;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      space_cv_.wait(lock, [&] { return stop_ || next_claim_ < next_give_ + config_.prefetch; });
      if (stop_) return;
      index = next_claim_++;
    }
    try {
      Batch b = batch(index);
      std::lock_guard<std::mutex> lock(mutex_);
      ready_[index] = std::move(b);
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex_);
      failed_[index] = std::current_exception();
    }
    ready_cv_.notify_all();
  }
}

Batch Loader::next() {
  if (config_.workers <= 0) return batch(next_give_++);
  std::unique_lock<std::mutex> lock(mutex_);
  if (threads_.empty()) {
    // The workers run their tensor work on one intra-op thread each, as
    // PyTorch's DataLoader workers do: N workers with a full OpenMP team each
    // would oversubscribe the cores that the training step uses. Their
    // at::set_num_threads(1) also sets the count of threads that start later,
    // so once every worker has set its own, this thread's count (unchanged)
    // is set again as that default.
    const int own = at::get_num_threads();
    std::mutex started_mutex;
    std::condition_variable started_cv;
    int64_t started = 0;
    for (int64_t i = 0; i < config_.workers; ++i)
      threads_.emplace_back([&, this] {
        at::set_num_threads(1);
        {
          std::lock_guard<std::mutex> l(started_mutex);
          ++started;
        }
        started_cv.notify_all();
        worker();
      });
    std::unique_lock<std::mutex> l(started_mutex);
    started_cv.wait(l, [&] { return started == config_.workers; });
    at::set_num_threads(own);
  }
  const int64_t index = next_give_;
  ready_cv_.wait(lock, [&] { return ready_.count(index) || failed_.count(index); });
  ++next_give_;
  space_cv_.notify_all();
  if (failed_.count(index)) {
    auto e = failed_[index];
    failed_.erase(index);
    std::rethrow_exception(e);
  }
  Batch b = std::move(ready_[index]);
  ready_.erase(index);
  return b;
}

}  // namespace flat::data
