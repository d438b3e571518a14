#include "flat/data/loader.h"

#include <algorithm>
#include <filesystem>

#include <ATen/Parallel.h>
#include <spdlog/spdlog.h>

#include "flat/core/error.h"
#include "flat/core/exception_text.h"
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

// "latent set 176x320_f17 (17-frame windows at 176x320: data.height x data.width,
// data.input_frames) in scenes of 17+ frames", or "scenes of 17+ frames" without latents.
std::string stage_needs(const LoaderConfig& c) {
  const std::string frames = "scenes of " + std::to_string(frames_needed(c)) + "+ frames";
  if (!c.latents) return frames;
  return "latent set " + latent_set_key(c.height, c.width, c.input_frames) + " (" + std::to_string(c.input_frames) +
         "-frame windows at " + std::to_string(c.height) + "x" + std::to_string(c.width) +
         ": data.height x data.width, data.input_frames) in " + frames;
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

// Why a dataset's scenes were left out, beyond the report's counts: the
// latent sets those scenes hold and the lengths of those too short, so that an
// error can say what the data has next to what the stage asks for.
struct LeftOut {
  std::map<std::string, int64_t> sets;     // latent set -> left-out scenes holding it ("" = no latents)
  std::map<int64_t, int64_t> short_frames;  // frames -> scenes too short for one window
};

std::string scenes_count(int64_t n, const std::string& one, const std::string& many) {
  return std::to_string(n) + " " + (n == 1 ? one : many);
}

// "8x8_f5 (3 scenes), 16x16_f9 (1 scene), no latents (1 scene)"
std::string held_sets(const LeftOut& l) {
  std::string out;
  for (const auto& [set, n] : l.sets)
    out += (out.empty() ? "" : ", ") + (set.empty() ? std::string("no latents") : set) + " (" +
           scenes_count(n, "scene", "scenes") + ")";
  return out;
}

// One dataset's loss: what is left of it and why, with what its scenes hold.
std::string dataset_loss(const DatasetReport& r, const LeftOut& l, const LoaderConfig& c) {
  const std::string set = latent_set_key(c.height, c.width, c.input_frames);
  std::string line = "\n  dataset '" + r.root + "' (weight " + fmt::format("{}", r.weight) + "): ";
  line += r.used == 0 ? "no usable scene of " + std::to_string(r.found)
                      : std::to_string(r.missing_set) + " of " + std::to_string(r.found) + " scenes lack the set";
  std::vector<std::string> why;
  if (r.missing_set) why.push_back(std::to_string(r.missing_set) + " without latent set " + set);
  if (r.short_scenes) {
    std::string lengths;
    for (auto it = l.short_frames.rbegin(); it != l.short_frames.rend(); ++it)
      lengths += (lengths.empty() ? "" : ", ") + std::to_string(it->second) + (it->second == 1 ? " has " : " have ") +
                 std::to_string(it->first) + " frames";
    why.push_back(std::to_string(r.short_scenes) + " shorter than the " + std::to_string(frames_needed(c)) +
                  " frames one window spans (" + lengths + ")");
  }
  if (r.bad) why.push_back(std::to_string(r.bad) + " unreadable");
  for (size_t i = 0; i < why.size(); ++i) line += (i ? "; " : ": ") + why[i];
  if (c.latents && !l.sets.empty()) line += "; the scenes left out hold " + held_sets(l);
  if (!r.example_missing.empty()) line += " (e.g. " + r.example_missing + ")";
  return line;
}

// What makes the stage's data usable, for the datasets at fault.
std::string remedy(const std::vector<const DatasetReport*>& lost, const LoaderConfig& c) {
  bool missing = false, too_short = false;
  std::string roots;
  for (const auto* r : lost) {
    missing = missing || r->missing_set > 0;
    too_short = too_short || r->short_scenes > 0;
    if (r->missing_set > 0) roots += " " + r->root;
  }
  std::string out;
  if (missing && (c.height % 8 != 0 || c.width % 8 != 0))
    out += "\nNo latent set can be " + std::to_string(c.height) + "x" + std::to_string(c.width) +
           ": latents are made at multiples of 8 (the VAE's stride); give data.height and data.width of a set the "
           "scenes hold.";
  else if (missing)
    out += "\nMake the set: flat_latents --configs <this stage's config> (every set the config needs), or "
           "flat_latents --scenes" + roots + " --size " + std::to_string(c.height) + "x" + std::to_string(c.width) +
           " --window " + std::to_string(c.input_frames) +
           " with your VAE weights; or give data.height, data.width and data.input_frames of a set the scenes hold.";
  if (too_short)
    out += "\nScenes shorter than a window give no sample, whatever their latents: use scenes of " +
           std::to_string(frames_needed(c)) + "+ frames or a shorter window (data.input_frames" +
           (c.latents ? ", of a set the scenes hold" : "") + ").";
  return out;
}

// A mixture that silently loses a dataset trains on another distribution: with
// incomplete_datasets: fail that stops the run, naming every dataset at fault.
// With no usable scene anywhere the run stops in either mode. Every message
// carries what the stage needs and what the scenes hold (not only the log).
void check_dataset_reports(const std::vector<DatasetReport>& reports, const std::vector<LeftOut>& left_out,
                           const LoaderConfig& c) {
  std::string lines;
  std::vector<const DatasetReport*> lost;
  bool any_used = false;
  for (size_t i = 0; i < reports.size(); ++i) {
    const auto& r = reports[i];
    if (r.weight > 0 && r.used > 0) any_used = true;
    if ((r.weight > 0 && r.used == 0) || (r.missing_set && c.incomplete_datasets == "fail")) {
      lines += dataset_loss(r, left_out[i], c);
      lost.push_back(&r);
    }
  }
  const std::string needs = "this stage needs " + stage_needs(c) + ":";
  if (!any_used)
    fail("loader: no usable scenes in any dataset with a positive weight: " + needs + lines + remedy(lost, c));
  if (lost.empty()) return;
  const std::string what = "loader: " + needs + lines + remedy(lost, c);
  if (c.incomplete_datasets == "fail")
    fail(what + "\n(data.incomplete_datasets: fail; set data.incomplete_datasets: warn to train on what is there)");
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
  std::vector<LeftOut> left_out;
  for (const auto& src : config_.datasets) {
    LeftOut l;
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
      const bool too_short = scene->size() < frames_needed(config_);
      const bool lacks_set =
          !too_short && config_.latents && !find_latent_set(*scene, config_.height, config_.width, config_.input_frames);
      if (too_short || lacks_set) {
        if (scene->latent_sets.empty()) ++l.sets[""];
        for (const auto& set : scene->latent_sets) ++l.sets[latent_set_key(set)];
      }
      if (too_short) {
        ++r.short_scenes;
        ++l.short_frames[scene->size()];
        continue;
      }
      if (config_.latents) {
        // The set of this stage's size and window; the scene's other sets are not read.
        if (lacks_set) {
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
    left_out.push_back(std::move(l));
    datasets_.push_back(std::move(d));
  }
  check_dataset_reports(reports_, left_out, config_);
  double total = 0;
  for (const auto& d : datasets_) total += d.scenes.empty() ? 0 : d.weight;
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
      const std::string why = exception_text(e);
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
