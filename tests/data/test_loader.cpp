// Loader: determinism, seen/unseen split, resizing with intrinsics, weighted
// mixing, bad scenes (fail naming them, or skip and count), packed scenes, latents.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <set>
#include <thread>

#include <ATen/Parallel.h>

#include "flat/core/error.h"
#include "flat/data/loader.h"
#include "flat/data/pack.h"
#include "flat/data/scene_frames.h"
#include "flat/data/scene_latents.h"
#include "flat/data/synthetic_scene.h"
#include "flat/data/view_sampler.h"
#include "data_test_dirs.h"
#include "support/read_file.h"
#include "test_support.h"

using namespace flat;
using flat::test::read_file;
namespace fs = std::filesystem;

namespace {

// A dataset folder of `n` tiny synthetic scenes of `frames` frames.
fs::path make_dataset(const std::string& name, int n, int64_t frames = 13, const std::string& family = "room") {
  auto root = test::fresh_dir(name);
  for (int i = 0; i < n; ++i) {
    data::SynthOptions o;
    o.family = family;
    o.frames = frames;
    o.height = 12;
    o.width = 16;
    o.seed = uint64_t(100 * i + frames);
    auto s = data::render_synthetic_scene(o);
    data::write_synthetic_scene(s, (root / ("s" + std::to_string(i))).string(), name + std::to_string(i), "test");
  }
  return root;
}

data::LoaderConfig tiny_config(const fs::path& root) {
  data::LoaderConfig c;
  c.datasets = {{root.string(), 1.0}};
  c.height = 8;
  c.width = 8;
  c.input_frames = 5;
  c.target_views = 6;
  c.batch_size = 2;
  c.workers = 2;
  c.prefetch = 2;
  c.seed = 3;
  return c;
}

bool same(const data::Batch& a, const data::Batch& b) {
  return a.scenes == b.scenes && torch::equal(a.target_frames, b.target_frames) &&
         torch::equal(a.input_frames, b.input_frames) && torch::equal(a.target_images, b.target_images) &&
         torch::equal(a.target_depth, b.target_depth) && torch::equal(a.target_c2w, b.target_c2w);
}

}  // namespace

TEST_CASE("view sampler: window of F frames, targets half seen inside, half unseen outside", "[data][loader]") {
  data::ViewSamplerConfig c;
  c.input_frames = 17;
  c.target_views = 17;
  for (uint64_t seed = 0; seed < 20; ++seed) {
    std::mt19937_64 rng(seed);
    auto v = data::sample_views(40, c, rng);
    REQUIRE(v.input.size() == 17);
    for (size_t i = 1; i < v.input.size(); ++i) CHECK(v.input[i] == v.input[i - 1] + 1);
    REQUIRE(v.targets.size() == 17);
    int seen = 0;
    std::set<int64_t> distinct(v.targets.begin(), v.targets.end());
    CHECK(distinct.size() == 17);
    for (size_t i = 0; i < v.targets.size(); ++i) {
      const bool inside = v.targets[i] >= v.input.front() && v.targets[i] <= v.input.back();
      CHECK(inside == bool(v.seen[i]));
      seen += v.seen[i];
    }
    CHECK(seen == 9);  // 17 = 9 seen + 8 unseen
  }
  // A video with no frames outside the window: all targets are seen.
  std::mt19937_64 rng(1);
  auto v = data::sample_views(17, c, rng);
  CHECK(std::all_of(v.seen.begin(), v.seen.end(), [](bool s) { return s; }));
  // Unseen targets within the gap limit.
  c.unseen_max_gap = 2;
  c.target_views = 4;
  std::mt19937_64 rng2(2);
  auto g = data::sample_views(60, c, rng2);
  for (size_t i = 0; i < g.targets.size(); ++i)
    if (!g.seen[i]) CHECK((g.targets[i] >= g.input.front() - 2 && g.targets[i] <= g.input.back() + 2));
  // Too short.
  std::mt19937_64 rng3(3);
  REQUIRE_THROWS_WITH(data::sample_views(10, c, rng3), FLAT_CONTAINS("scene has 10 frames, a window needs 17"));
}

TEST_CASE("loader batches are deterministic for a seed, with or without prefetch threads", "[data][loader]") {
  auto root = make_dataset("loader_det", 3);
  auto c = tiny_config(root);
  data::Loader threaded(c);
  std::vector<data::Batch> first;
  for (int i = 0; i < 4; ++i) first.push_back(threaded.next());
  c.workers = 0;
  data::Loader serial(c);
  for (int i = 0; i < 4; ++i) CHECK(same(first[size_t(i)], serial.next()));
  c.seed = 4;
  data::Loader other(c);
  bool differs = false;
  for (int i = 0; i < 4; ++i) differs = differs || !same(first[size_t(i)], other.next());
  CHECK(differs);

  const auto& b = first[0];
  CHECK(b.target_images.sizes() == torch::IntArrayRef({2, 6, 3, 8, 8}));
  CHECK(b.target_depth.sizes() == torch::IntArrayRef({2, 6, 1, 8, 8}));
  CHECK(b.target_normals.sizes() == torch::IntArrayRef({2, 6, 3, 8, 8}));
  CHECK(b.input_c2w.sizes() == torch::IntArrayRef({2, 5, 4, 4}));
  CHECK(b.target_seen.sum().item<int64_t>() == 2 * 3);
  // Seen flags agree with the window.
  for (int64_t s = 0; s < 2; ++s)
    for (int64_t v = 0; v < 6; ++v) {
      auto f = b.target_frames[s][v].item<int64_t>();
      bool inside = f >= b.input_frames[s][0].item<int64_t>() && f <= b.input_frames[s][4].item<int64_t>();
      CHECK(inside == b.target_seen[s][v].item<bool>());
    }
}

TEST_CASE("loader resizes frames with a centred crop; intrinsics follow", "[data][loader]") {
  auto root = make_dataset("loader_resize", 1);
  auto c = tiny_config(root);
  c.workers = 0;
  c.batch_size = 1;
  auto b = data::Loader(c).next();  // 12x16 -> crop 12x12 -> 8x8
  auto scene = data::read_scene((root / "s0").string());
  auto f = b.target_frames[0][0].item<int64_t>();
  auto k = scene.frames[size_t(f)].intrinsics.to(torch::kDouble);
  auto got = b.target_intrinsics[0][0].to(torch::kDouble);
  // fx_pix = fxn*16 is kept; normalised by the 12-pixel crop width. cx: (0.5*16 - 2)/12 = 0.5.
  CHECK(got[0].item<double>() == Approx(k[0].item<double>() * 16 / 12).epsilon(1e-6));
  CHECK(got[1].item<double>() == Approx(k[1].item<double>()).epsilon(1e-6));
  CHECK(got[2].item<double>() == Approx(0.5).epsilon(1e-6));
  // A 2:1 depth downsample by nearest keeps exact depth values from the crop.
  auto depth = data::load_frames(scene, {f}, true, false).depth;
  auto crop = depth.slice(3, 2, 14);
  for (int64_t y = 0; y < 8; ++y)
    for (int64_t x = 0; x < 8; ++x) {
      float d = b.target_depth[0][0][0][y][x].item<float>();
      const float nearest = (crop[0][0] - d).abs().min().item<float>();
      CHECK(nearest == 0.0f);
    }
  CHECK(b.target_images.min().item<float>() >= -1e-6);
  CHECK(b.target_images.max().item<float>() <= 1 + 1e-6);
}

TEST_CASE("loader mixes datasets by weight", "[data][loader]") {
  auto a = make_dataset("loader_mix_a", 1);
  auto b = make_dataset("loader_mix_b", 1, 13, "object");
  data::LoaderConfig c = tiny_config(a);
  c.datasets = {{a.string(), 3.0}, {b.string(), 1.0}};
  c.workers = 0;
  c.batch_size = 1;
  c.depth = c.normals = false;
  data::Loader loader(c);
  int from_a = 0;
  const int n = 200;
  for (int i = 0; i < n; ++i) from_a += loader.sample(i).scene_dir.find("loader_mix_a") != std::string::npos;
  INFO(from_a << " of " << n << " from the weight-3 dataset");
  CHECK(from_a > 0.75 * n - 25);
  CHECK(from_a < 0.75 * n + 25);
  c.datasets[1].weight = 0;
  data::Loader only_a(c);
  for (int i = 0; i < 20; ++i) CHECK(only_a.sample(i).scene_dir.find("loader_mix_a") != std::string::npos);
}

TEST_CASE("loader: a corrupt scene fails naming scene and file, or is skipped and counted", "[data][loader]") {
  auto root = make_dataset("loader_bad", 3);
  auto scene = data::read_scene((root / "s1").string());
  std::ofstream(root / "s1" / scene.frames[2].depth) << "garbage";
  fs::remove(root / "s1" / scene.frames[7].image);
  auto c = tiny_config(root);
  c.workers = 0;
  c.batch_size = 1;
  // Missing file: found when the scene is indexed.
  REQUIRE_THROWS_WITH(data::Loader(c), FLAT_CONTAINS("frames[7]: image"));
  c.skip_bad_scenes = true;
  data::Loader skipping(c);
  CHECK(skipping.skipped_scenes() == 1);
  CHECK(skipping.scene_count() == 2);
  for (int i = 0; i < 10; ++i) CHECK(skipping.next().scenes[0] != "loader_bad1");
  // Corrupt file: found when loaded.
  data::write_synthetic_scene(data::render_synthetic_scene({"room", "mixed", 13, 12, 16, 99}), (root / "s1").string(),
                              "loader_bad1", "test");
  std::ofstream(root / "s1" / scene.frames[2].depth) << "garbage";
  c.skip_bad_scenes = false;
  c.input_frames = 13;  // every sample reads all frames of a scene
  c.target_views = 13;
  c.unseen_fraction = 0;
  bool failed_named = false;
  data::Loader strict(c);
  try {
    for (int i = 0; i < 40; ++i) strict.next();
  } catch (const Error& e) {
    std::string m = e.what();
    failed_named = m.find("loader_bad1") != std::string::npos && m.find(scene.frames[2].depth) != std::string::npos;
    INFO(m);
  }
  CHECK(failed_named);
  c.skip_bad_scenes = true;
  c.workers = 2;
  data::Loader skip2(c);
  for (int i = 0; i < 30; ++i) CHECK(skip2.next().scenes[0] != "loader_bad1");
  CHECK(skip2.skipped_scenes() == 1);
}

TEST_CASE("loader reads packed scenes and precomputed latents", "[data][loader]") {
  auto root = make_dataset("loader_packed", 2);
  auto c = tiny_config(root);
  c.workers = 0;
  data::Loader files(c);
  auto want = files.next();
  for (const char* s : {"s0", "s1"}) {
    auto scene = data::read_scene((root / s).string());
    data::pack_scene(scene, true);
  }
  data::Loader packed(c);
  auto got = packed.next();
  CHECK(torch::allclose(got.target_images, want.target_images, 0, 1e-6));  // PNG and pack both hold 8-bit RGB
  CHECK(torch::equal(got.target_depth, want.target_depth));
  CHECK((got.target_normals - want.target_normals).abs().max().item<float>() < 2e-3);

  // Latents: windows [0,5) and [8,13) at 8x8; the loader picks one of them as the input window.
  for (const char* s : {"s0", "s1"}) {
    auto scene = data::read_scene((root / s).string());
    data::LatentInfo info;
    info.encoder = "random";
    info.height = 8;
    info.width = 8;
    info.windows = {{0, 5}, {8, 5}};
    std::vector<data::WindowLatents> l;
    for (int w = 0; w < 2; ++w) l.push_back({torch::full({16, 2, 1, 1}, float(w)), torch::full({32, 2, 1, 1}, float(w))});
    data::write_scene_latents(scene, info, l);
  }
  c.latents = true;
  data::Loader with_latents(c);
  for (int i = 0; i < 4; ++i) {
    auto b = with_latents.next();
    REQUIRE(b.video_latents.sizes() == torch::IntArrayRef({2, 16, 2, 1, 1}));
    for (int64_t s = 0; s < 2; ++s) {
      int64_t start = b.input_frames[s][0].item<int64_t>();
      CHECK((start == 0 || start == 8));
      CHECK(b.video_latents[s][0][0][0][0].item<float>() == (start == 0 ? 0.0f : 1.0f));
    }
  }
  c.height = 16;  // latents were encoded at 8x8: no usable scenes at 16x16
  c.width = 16;
  REQUIRE_THROWS_WITH(data::Loader(c), FLAT_CONTAINS("no usable scenes"));
}

TEST_CASE("loader: a start batch resumes the stream; ranks split it without overlap", "[data][loader]") {
  auto root = make_dataset("loader_ranks", 3);
  auto c = tiny_config(root);
  c.batch_size = 1;
  // One process with batch 2 reads samples 2b, 2b+1 as its batch b ...
  auto combined = c;
  combined.batch_size = 2;
  combined.workers = 0;
  data::Loader whole(combined);
  // ... rank r of 2 with batch 1 reads sample 2b + r.
  data::Loader rank0(c, 0, 0, 2), rank1(c, 0, 1, 2);
  for (int64_t b = 0; b < 3; ++b) {
    auto w = whole.next(), r0 = rank0.next(), r1 = rank1.next();
    CHECK(w.scenes[0] == r0.scenes[0]);
    CHECK(w.scenes[1] == r1.scenes[0]);
    CHECK(torch::equal(w.target_frames[0], r0.target_frames[0]));
    CHECK(torch::equal(w.target_frames[1], r1.target_frames[0]));
    CHECK(torch::equal(w.target_images[1], r1.target_images[0]));
  }
  // Starting at batch 2 gives what the third next() gave, with or without threads.
  data::Loader from_start(c), resumed(c, 2);
  from_start.next();
  from_start.next();
  CHECK(same(from_start.next(), resumed.next()));
  CHECK(resumed.next_batch_index() == 3);
  REQUIRE_THROWS_WITH(data::Loader(c, 0, 2, 2), FLAT_CONTAINS("rank 2 of world size 2"));
}

TEST_CASE("loader: the camera latents the model reads (RPPC, or the Plucker ablation's)", "[data][loader]") {
  // Dataset "both": its scene holds RPPC (= 1) and Plucker (= 2) camera
  // latents; dataset "rppc": only RPPC.
  auto write = [](const fs::path& root, bool plucker) {
    auto scene = data::read_scene((root / "s0").string());
    data::LatentInfo info;
    info.encoder = "random";
    info.height = 8;
    info.width = 8;
    info.windows = {{0, 5}};
    data::WindowLatents l{torch::zeros({16, 2, 1, 1}), torch::full({32, 2, 1, 1}, 1.0f)};
    if (plucker) l.camera_plucker = torch::full({32, 2, 1, 1}, 2.0f);
    data::write_scene_latents(scene, info, {l});
    return data::read_scene((root / "s0").string());
  };
  auto both_root = make_dataset("loader_plucker_both", 1), rppc_root = make_dataset("loader_plucker_none", 1);
  auto both = write(both_root, true), rppc = write(rppc_root, false);
  CHECK(both.latents.plucker);
  CHECK_FALSE(rppc.latents.plucker);
  CHECK(data::read_window_latents(both, 0).camera.min().item<float>() == 1.0f);
  CHECK(data::read_window_latents(both, 0, "plucker").camera.min().item<float>() == 2.0f);
  REQUIRE_THROWS_WITH(data::read_window_latents(rppc, 0, "plucker"),
                      FLAT_CONTAINS("no Plucker camera latents") && FLAT_CONTAINS("--camera-rays rppc,plucker"));
  for (const auto& [root, want] : {std::make_pair(both_root, 2.0f), std::make_pair(rppc_root, -1.0f)}) {
    auto c = tiny_config(root);
    c.workers = 0;
    c.batch_size = 1;
    c.latents = true;
    c.camera_rays = "plucker";
    if (want > 0) {
      CHECK(data::Loader(c).next().camera_latents.min().item<float>() == want);
    } else {
      REQUIRE_THROWS_WITH(data::Loader(c).next(), FLAT_CONTAINS("no Plucker camera latents"));
    }
    c.camera_rays = "rppc";
    CHECK(data::Loader(c).next().camera_latents.min().item<float>() == 1.0f);
  }
}

TEST_CASE("loader workers leave the caller's intra-op threads, and those of threads started later, as they were",
          "[data][loader]") {
  // The workers set one intra-op thread each (at::set_num_threads(1)), which
  // is also the default of every thread that starts afterwards unless the
  // loader sets the caller's count back.
  auto root = make_dataset("loader_threads", 2);
  int caller = 0, later = 0;
  std::thread t([&] {
    const int before = at::get_num_threads();
    at::set_num_threads(3);
    auto c = tiny_config(root);
    c.workers = 2;
    {
      data::Loader loader(c);
      loader.next();
      caller = at::get_num_threads();
      std::thread after([&] { later = at::get_num_threads(); });
      after.join();
    }
    at::set_num_threads(before);
  });
  t.join();
  CHECK(caller == 3);
  CHECK(later == 3);
}

namespace {

// One latent set (windows of `frames` at h x w) whose every value is `value`.
void add_set(const fs::path& scene_dir, int64_t h, int64_t w, int64_t frames, float value) {
  auto scene = data::read_scene(scene_dir.string());
  data::LatentInfo info;
  info.encoder = "random";
  info.height = h;
  info.width = w;
  info.windows = {{0, frames}};
  const int64_t t = 1 + (frames - 1) / 4;
  data::write_scene_latents(scene, info,
                            {{torch::full({16, t, h / 8, w / 8}, value), torch::full({32, t, h / 8, w / 8}, value)}});
}

}  // namespace

TEST_CASE("latent sets: a scene holds one per size and window; the loader reads the stage's own", "[data][loader]") {
  auto root = make_dataset("loader_sets", 2, 13);
  for (const char* s : {"s0", "s1"}) add_set(root / s, 8, 8, 5, 1.0f);
  const auto first = root / "s0" / "latents_8x8_f5.safetensors";
  REQUIRE(fs::exists(first));
  const std::string first_bytes = read_file(first);
  for (const char* s : {"s0", "s1"}) add_set(root / s, 16, 16, 9, 2.0f);
  // The second set left the first's file byte-identical and both are listed.
  CHECK(read_file(first) == first_bytes);
  auto scene = data::read_scene((root / "s0").string());
  CHECK(data::latent_set_list(scene) == "8x8_f5, 16x16_f9");
  CHECK_FALSE(scene.latents.present());  // two sets: none is chosen for the reader
  REQUIRE_THROWS_WITH(data::read_window_latents(scene, 0), FLAT_CONTAINS("several latent sets"));
  REQUIRE_THROWS_WITH(data::choose_latent_set(scene, ""), FLAT_CONTAINS("--latent-set"));
  data::choose_latent_set(scene, "16x16_f9");
  CHECK(data::read_window_latents(scene, 0).video.min().item<float>() == 2.0f);
  REQUIRE_THROWS_WITH(data::choose_latent_set(scene, "16x16_f17"),
                      FLAT_CONTAINS("no latent set 16x16_f17") && FLAT_CONTAINS("8x8_f5, 16x16_f9"));
  REQUIRE_THROWS_WITH(data::choose_latent_set(scene, "16x16"), FLAT_CONTAINS("HEIGHTxWIDTH_fFRAMES"));
  // The loader of each stage reads its own set.
  auto c = tiny_config(root);
  c.workers = 0;
  c.latents = true;
  c.target_views = 4;
  CHECK(data::Loader(c).next().video_latents.min().item<float>() == 1.0f);
  c.height = 16;
  c.width = 16;
  c.input_frames = 9;
  auto b = data::Loader(c).next();
  CHECK(b.video_latents.min().item<float>() == 2.0f);
  CHECK(b.video_latents.size(2) == 3);
  // Replacing a set keeps the other one's file.
  add_set(root / "s0", 16, 16, 9, 3.0f);
  CHECK(read_file(first) == first_bytes);
}

TEST_CASE("loader: a mixture losing a dataset's scenes is named per dataset, and fails when the key says so",
          "[data][loader]") {
  auto a = make_dataset("loader_mix_a", 2, 13);
  auto b = make_dataset("loader_mix_b", 3, 13);
  for (const char* s : {"s0", "s1"}) add_set(a / s, 8, 8, 5, 1.0f);
  add_set(b / "s0", 8, 8, 5, 2.0f);
  add_set(b / "s1", 16, 16, 9, 2.0f);  // another stage's set only
  // b/s2 has no latents at all.
  auto c = tiny_config(a);
  c.datasets = {{a.string(), 0.5}, {b.string(), 0.5}};
  c.workers = 0;
  c.latents = true;
  c.target_views = 4;
  {
    data::Loader warn(c);
    REQUIRE(warn.reports().size() == 2);
    const auto& rb = warn.reports()[1];
    CHECK(rb.found == 3);
    CHECK(rb.used == 1);
    CHECK(rb.missing_set == 2);
    CHECK(rb.other_sets.count("16x16_f9") == 1);
    CHECK(rb.other_sets.count("none") == 1);
    CHECK(warn.reports()[0].used == 2);
    CHECK(warn.reports()[0].with_depth == 2);
  }
  c.incomplete_datasets = "fail";
  REQUIRE_THROWS_WITH(data::Loader(c), FLAT_CONTAINS(b.string()) && FLAT_CONTAINS("2 of 3 scenes lack") &&
                                           FLAT_CONTAINS("8x8_f5") && FLAT_CONTAINS("incomplete_datasets"));
  // A dataset left with no scene at all: named in both modes; fails only with the key.
  add_set(b / "s0", 16, 16, 9, 2.0f);
  {
    auto j = data::read_scene((b / "s0").string());
    j.latent_sets.erase(std::remove_if(j.latent_sets.begin(), j.latent_sets.end(),
                                       [](const data::LatentInfo& l) { return l.height == 8; }),
                        j.latent_sets.end());
    j.latents = {};
    data::write_scene_json(j);
    fs::remove(b / "s0" / "latents_8x8_f5.safetensors");
  }
  REQUIRE_THROWS_WITH(data::Loader(c), FLAT_CONTAINS("no usable scene of 3"));
  c.incomplete_datasets = "warn";
  data::Loader lost(c);
  CHECK(lost.reports()[1].used == 0);
  CHECK(lost.scene_count() == 2);
  // The stage asks for a set no dataset has: the error says what the stage needs.
  c.input_frames = 9;
  c.height = 32;
  c.width = 32;
  REQUIRE_THROWS_WITH(data::Loader(c), FLAT_CONTAINS("32x32_f9") && FLAT_CONTAINS("no usable scenes"));
}

// Issue #45: a stage whose size or window differs from the scenes' latents
// stopped with "no usable scenes in any dataset with a positive weight" alone.
// The error itself now says which set the stage needs, which sets the scenes
// hold (with counts) and what makes the set, in both incomplete_datasets modes.
TEST_CASE("loader: a stage whose size or window the scenes' latents lack names the set it needs, the sets they hold "
          "and the command that makes it",
          "[data][loader]") {
  auto root = make_dataset("loader_stage_mismatch", 3, 9);
  for (const char* s : {"s0", "s1", "s2"}) add_set(root / s, 8, 8, 5, 1.0f);
  add_set(root / "s2", 16, 16, 9, 2.0f);
  auto c = tiny_config(root);
  c.workers = 0;
  c.latents = true;
  c.target_views = 4;
  for (const std::string mode : {"warn", "fail"}) {
    INFO("incomplete_datasets: " << mode);
    c.incomplete_datasets = mode;
    // Another size (data.height): 16x8_f5 is needed; 3 scenes hold 8x8_f5, 1 holds 16x16_f9.
    c.height = 16;
    c.width = 8;
    c.input_frames = 5;
    REQUIRE_THROWS_WITH(data::Loader(c), FLAT_CONTAINS("no usable scene") && FLAT_CONTAINS("latent set 16x8_f5") &&
                                             FLAT_CONTAINS("8x8_f5 (3 scenes)") &&
                                             FLAT_CONTAINS("16x16_f9 (1 scene)") && FLAT_CONTAINS(root.string()) &&
                                             FLAT_CONTAINS("flat_latents --configs") &&
                                             FLAT_CONTAINS("--size 16x8 --window 5"));
    // Another window the scenes are long enough for (data.input_frames): 8x8_f9 is needed.
    c.height = 8;
    c.input_frames = 9;
    REQUIRE_THROWS_WITH(data::Loader(c), FLAT_CONTAINS("latent set 8x8_f9") && FLAT_CONTAINS("8x8_f5 (3 scenes)") &&
                                             FLAT_CONTAINS("flat_latents --configs"));
    // A size no latent set can have (not a multiple of 8): said instead of a command that would refuse it.
    c.height = 12;
    c.input_frames = 5;
    REQUIRE_THROWS_WITH(data::Loader(c), FLAT_CONTAINS("latent set 12x8_f5") && FLAT_CONTAINS("multiples of 8") &&
                                             FLAT_CONTAINS("8x8_f5 (3 scenes)"));
    c.height = 8;
    // A window longer than the scenes (data.input_frames 13 on 9-frame scenes): their
    // length and the sets they hold, and that a set alone does not help.
    c.input_frames = 13;
    REQUIRE_THROWS_WITH(data::Loader(c), FLAT_CONTAINS("latent set 8x8_f13") && FLAT_CONTAINS("3 have 9 frames") &&
                                             FLAT_CONTAINS("8x8_f5 (3 scenes)") &&
                                             FLAT_CONTAINS("data.input_frames"));
  }
}
