// flat_infer's job end to end on a tiny random-weight decoder and a synthetic
// scene: what it writes, that streaming and full decoding agree, and that bad
// inputs fail clearly without leaving anything half-written.
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "flat/camera/camera_json.h"
#include "flat/core/image_io.h"
#include "flat/core/tensor_io.h"
#include "flat/export/triangle_ply.h"
#include "flat/infer/inference.h"
#include "flat/infer/trajectory_renders.h"
#include "model_fixtures.h"
#include "support/read_file.h"
#include "test_support.h"

namespace fs = std::filesystem;
using flat::test::read_file;
using namespace flat;

namespace {

struct Setup {
  fs::path dir;
  std::string model, scene;
};

Setup setup(const std::string& name) {
  Setup s;
  s.dir = test::scratch_dir(name);
  s.model = (s.dir / "model.safetensors").string();
  test::write_tiny_model(s.model);
  s.scene = (s.dir / "room").string();
  test::write_scene_with_latents(s.scene, 3);
  return s;
}

infer::InferOptions options(const Setup& s, const std::string& out) {
  infer::InferOptions o;
  o.model = s.model;
  o.input.scene_dir = s.scene;
  o.out_dir = (s.dir / out).string();
  o.device = "cpu";
  o.prune_opacity = 0.0;
  o.novel.frames = 6;
  o.video = false;   // tested in the export module; keeps this test independent of ffmpeg
  o.viewer = false;
  o.log_level = "warn";
  return o;
}

// The same options with the scene PLY as the only output (no renders, novel views nor GLB).
infer::InferOptions ply_only_options(const Setup& s, const std::string& out) {
  infer::InferOptions o = options(s, out);
  o.renders = false;
  o.novel.preset = "none";
  o.glb = false;
  return o;
}

bool no_staging_left(const fs::path& dir) {
  for (const auto& e : fs::directory_iterator(dir))
    if (e.path().filename().string().find(".incomplete-") != std::string::npos) return false;
  return true;
}

}  // namespace

TEST_CASE("flat_infer decodes a scene window and writes PLY, cameras, renders and a summary", "[infer]") {
  auto s = setup("infer_basic");
  auto o = options(s, "out");
  o.glb = false;
  auto summary = infer::run_inference(o);
  const fs::path out = o.out_dir;
  // 9 frames of 48x80 -> one triangle per 2x2 block of every frame.
  CHECK(summary.triangles_decoded == 9 * 24 * 40);
  CHECK(summary.triangles_kept == summary.triangles_decoded);  // prune 0 keeps all
  auto ply = exporter::read_triangle_ply((out / "scene.ply").string());
  CHECK(ply.vertices.size(0) == summary.triangles_kept);
  auto input = camera::read_cameras_json((out / "cameras/input.json").string());
  CHECK(input.cameras.size() == 9);
  CHECK(input.width == 80);
  auto novel = camera::read_cameras_json((out / "cameras/novel.json").string());
  CHECK(novel.cameras.size() == 6);
  CHECK(summary.input_views == 9);
  CHECK(summary.novel_views == 6);
  if (image_io_available()) {
    CHECK(fs::exists(out / "renders/input/rgb/000008.png"));
    CHECK(fs::exists(out / "renders/novel/normal/000005.png"));
    auto img = read_image((out / "renders/input/rgb/000000.png").string());
    CHECK(img.size(1) == 48);
    CHECK(img.size(2) == 80);
  } else {
    CHECK(fs::exists(out / "renders/input/000008.safetensors"));
  }
  auto j = nlohmann::json::parse(read_file(out / "summary.json"));
  CHECK(j.at("triangles_kept").get<int64_t>() == summary.triangles_kept);
  CHECK(j.at("novel_trajectory").get<std::string>() == "orbit");  // which novel views these are
  CHECK(infer::format_summary(summary).find("kept (100.0%, opacity >= 0)") != std::string::npos);
  CHECK(j.at("latent_encoder").get<std::string>() == "random");
  CHECK(fs::exists(out / "infer.log"));
  CHECK(no_staging_left(s.dir));
}

TEST_CASE("flat_infer: novel views that look past the scene are reported, not passed off", "[infer]") {
  const auto s = setup("infer_uncovered");
  auto o = options(s, "wide");
  o.novel.degrees = 80;  // far past what 9 frames of a pan saw
  const auto summary = infer::run_inference(o);
  INFO(infer::format_summary(summary));
  CHECK(summary.novel_uncovered > summary.input_uncovered + 0.01);
  bool noted = false;
  for (const auto& n : summary.notes) noted |= n.find("uncovered") != std::string::npos;
  CHECK(noted);
  const auto j = nlohmann::json::parse(read_file(fs::path(o.out_dir) / "summary.json"));
  CHECK(j["uncovered_pixels"]["novel"].get<double>() == Approx(summary.novel_uncovered));
  // The input views themselves are covered.
  CHECK(summary.input_uncovered < 0.05);
}

TEST_CASE("flat_infer: pruning keeps exactly the triangles at or above the threshold", "[infer]") {
  auto s = setup("infer_prune");
  auto o = ply_only_options(s, "all");
  infer::run_inference(o);
  auto all = exporter::read_triangle_ply(o.out_dir + "/scene.ply");
  const double threshold = all.opacities.median().item<double>();
  auto o2 = ply_only_options(s, "pruned");
  o2.prune_opacity = threshold;
  auto summary = infer::run_inference(o2);
  auto kept = exporter::read_triangle_ply(o2.out_dir + "/scene.ply");
  CHECK(kept.vertices.size(0) == (all.opacities >= float(threshold)).sum().item<int64_t>());
  CHECK(summary.triangles_kept < summary.triangles_decoded);
  CHECK(kept.opacities.min().item<double>() >= float(threshold));
}

TEST_CASE("flat_infer: by default it prunes as the model was trained, else at 0.05", "[infer]") {
  auto s = setup("infer_prune_default");
  auto o = ply_only_options(s, "all");
  infer::run_inference(o);
  const auto all = exporter::read_triangle_ply(o.out_dir + "/scene.ply");
  const float threshold = all.opacities.median().item<float>();
  // A model trained with pruning (its pipeline.prune_opacity, here layered over
  // the tiny model's config): the export keeps what it was trained to render.
  auto trained = ply_only_options(s, "model_threshold");
  trained.prune_opacity = -1;  // the default
  char key[64];
  std::snprintf(key, sizeof key, "prune_opacity=%.9g", threshold);
  trained.overrides = {key};
  auto summary = infer::run_inference(trained);
  CHECK(summary.prune_opacity == Approx(threshold));
  CHECK(exporter::read_triangle_ply(trained.out_dir + "/scene.ply").vertices.size(0) ==
        (all.opacities >= threshold).sum().item<int64_t>());
  // A model trained without pruning: 0.05.
  auto untrained = ply_only_options(s, "no_threshold");
  untrained.prune_opacity = -1;
  summary = infer::run_inference(untrained);
  CHECK(summary.prune_opacity == Approx(infer::kDefaultPruneOpacity));
  CHECK(summary.triangles_kept == (all.opacities >= float(infer::kDefaultPruneOpacity)).sum().item<int64_t>());
}

TEST_CASE("flat_infer: streaming and full-sequence decoding export the same triangles", "[infer]") {
  auto s = setup("infer_streaming");
  auto a = ply_only_options(s, "streaming");
  auto b = a;
  b.out_dir = (s.dir / "full").string();
  b.streaming = false;
  infer::run_inference(a);
  infer::run_inference(b);
  auto ta = exporter::read_triangle_ply(a.out_dir + "/scene.ply");
  auto tb = exporter::read_triangle_ply(b.out_dir + "/scene.ply");
  REQUIRE(ta.vertices.sizes() == tb.vertices.sizes());
  CHECK(test::rel_error(ta.vertices, tb.vertices) < 1e-5);
  CHECK(test::rel_error(ta.colors, tb.colors) < 1e-5);
}

TEST_CASE("flat_infer: a latent file with a trajectory, and latents that do not match it", "[infer]") {
  auto s = setup("infer_files");
  // 3 latent frames -> 9 frames; the scene's 9 first cameras are the trajectory.
  auto scene = data::read_scene(s.scene);
  auto w = data::read_window_latents(scene, 0);
  const std::string latents = (s.dir / "z.safetensors").string();
  save_safetensors(latents, {{"video", w.video}, {"camera", w.camera}});
  std::vector<int64_t> first9{0, 1, 2, 3, 4, 5, 6, 7, 8};
  const std::string cams = (s.dir / "traj.json").string();
  camera::write_cameras_json(cams, {scene.cameras(first9), 80, 48});
  auto o = options(s, "from_files");
  o.input = {};
  o.input.latents_file = latents;
  o.input.cameras_file = cams;
  o.renders = false;
  o.glb = false;
  auto summary = infer::run_inference(o);
  CHECK(summary.triangles_decoded == 9 * 24 * 40);

  // 8 cameras for 9 frames: refused, naming both files and the counts.
  std::vector<int64_t> first8{0, 1, 2, 3, 4, 5, 6, 7};
  const std::string cams8 = (s.dir / "traj8.json").string();
  camera::write_cameras_json(cams8, {scene.cameras(first8), 80, 48});
  auto bad = o;
  bad.out_dir = (s.dir / "bad").string();
  bad.input.cameras_file = cams8;
  REQUIRE_THROWS_WITH(infer::run_inference(bad), FLAT_CONTAINS("8 cameras") && FLAT_CONTAINS("z.safetensors"));
  CHECK(!fs::exists(bad.out_dir));
  // Camera latents missing and no VAE to encode them.
  save_safetensors(latents, {{"video", w.video}});
  bad.input.cameras_file = cams;
  REQUIRE_THROWS_WITH(infer::run_inference(bad), FLAT_CONTAINS("--vae"));
  // A wrongly shaped latent.
  save_safetensors(latents, {{"video", w.video.slice(0, 0, 8)}});
  REQUIRE_THROWS_WITH(infer::run_inference(bad), FLAT_CONTAINS("'video'") && FLAT_CONTAINS("(8,"));
  CHECK(!fs::exists(bad.out_dir));
  CHECK(no_staging_left(s.dir));
}

TEST_CASE("flat_infer: bad model, output folder and input fail before anything is written", "[infer]") {
  auto s = setup("infer_bad");
  auto good = ply_only_options(s, "out");
  infer::run_inference(good);
  const std::string before = read_file(fs::path(good.out_dir) / "scene.ply");

  SECTION("an existing output folder is refused without --overwrite, and kept") {
    REQUIRE_THROWS_WITH(infer::run_inference(good), FLAT_CONTAINS("already exists") && FLAT_CONTAINS("--overwrite"));
    CHECK(read_file(fs::path(good.out_dir) / "scene.ply") == before);
  }
  SECTION("a run that fails midway with --overwrite leaves the old output as it was") {
    auto o = good;
    o.overwrite = true;
    o.input.window = 5;  // the scene has one window
    REQUIRE_THROWS_WITH(infer::run_inference(o), FLAT_CONTAINS("--window-index 5") && FLAT_CONTAINS("scene.json"));
    CHECK(read_file(fs::path(good.out_dir) / "scene.ply") == before);
    CHECK(no_staging_left(s.dir));
  }
  SECTION("an unwritable output folder") {
    std::ofstream(s.dir / "a_file") << "x";
    auto o = good;
    o.out_dir = (s.dir / "a_file" / "out").string();
    REQUIRE_THROWS_WITH(infer::run_inference(o), FLAT_CONTAINS("a_file"));
  }
  SECTION("a checkpoint of another width than the config given") {
    const std::string wide = (s.dir / "wide.safetensors").string();
    test::write_tiny_model(wide, 16);
    const std::string cfg = (s.dir / "dim8.yaml").string();
    std::ofstream(cfg) << "pipeline:\n  model:\n    vae: {dim: 8}\n  triangles: {depth_far: 12.0}\n";
    auto o = good;
    o.model = wide;
    o.config = cfg;
    o.out_dir = (s.dir / "wide_out").string();
    REQUIRE_THROWS_WITH(infer::run_inference(o),
                        FLAT_CONTAINS("wide.safetensors") && FLAT_CONTAINS("vae.dim: checkpoint 16, this config 8"));
    CHECK(!fs::exists(o.out_dir));
  }
  SECTION("a truncated model file") {
    const std::string cut = (s.dir / "cut.safetensors").string();
    const std::string bytes = read_file(s.model);
    std::ofstream(cut, std::ios::binary) << bytes.substr(0, bytes.size() / 2);
    auto o = good;
    o.model = cut;
    o.out_dir = (s.dir / "cut_out").string();
    REQUIRE_THROWS_WITH(infer::run_inference(o), FLAT_CONTAINS("cut.safetensors"));
    CHECK(!fs::exists(o.out_dir));
  }
  // Options that read `video` (and the scene's own camera latents) from a
  // latents file beside the scene's first 9 cameras, into out_dir.
  auto from_latents_file = [&](const std::string& name, const at::Tensor& video, const std::string& out_dir) {
    auto scene = data::read_scene(s.scene);
    auto w = data::read_window_latents(scene, 0);
    const std::string z = (s.dir / name).string();
    save_safetensors(z, {{"video", video.defined() ? video : w.video}, {"camera", w.camera}});
    std::vector<int64_t> first9{0, 1, 2, 3, 4, 5, 6, 7, 8};
    const std::string cams = (s.dir / "traj.json").string();
    camera::write_cameras_json(cams, {scene.cameras(first9), 80, 48});
    auto o = good;
    o.input = {};
    o.input.latents_file = z;
    o.input.cameras_file = cams;
    o.out_dir = (s.dir / out_dir).string();
    return o;
  };
  auto window_video = [&] { return data::read_window_latents(data::read_scene(s.scene), 0).video; };
  SECTION("NaN latents") {
    auto video = window_video();
    video[0][0][0][0] = NAN;
    auto o = from_latents_file("nan.safetensors", video, "nan_out");
    REQUIRE_THROWS_WITH(infer::run_inference(o), FLAT_CONTAINS("nan.safetensors") && FLAT_CONTAINS("NaN"));
    CHECK(!fs::exists(o.out_dir));
  }
  SECTION("int64 latents are a wrong file, not values to convert") {
    auto o = from_latents_file("int64.safetensors", window_video().round().to(at::kLong), "int64_out");
    REQUIRE_THROWS_WITH(infer::run_inference(o), FLAT_CONTAINS("int64.safetensors: 'video' has dtype Long") &&
                                                     FLAT_CONTAINS("floating point"));
    CHECK(!fs::exists(o.out_dir));
  }
  SECTION("a model file with an int64 tensor or a NaN weight is named at load") {
    Metadata meta;
    auto tensors = load_safetensors(s.model, &meta);
    const std::string key = tensors.begin()->first;
    for (const char* fault : {"int64", "nan"}) {
      auto bad = tensors;
      auto t = bad.at(key).clone();
      if (std::string(fault) == "nan") t.view(-1)[3] = NAN;
      else t = t.round().to(at::kLong);
      bad[key] = t;
      const std::string file = (s.dir / (std::string(fault) + "_model.safetensors")).string();
      save_safetensors(file, bad, meta);
      auto o = good;
      o.model = file;
      o.out_dir = (s.dir / (std::string(fault) + "_model_out")).string();
      INFO(fault);
      REQUIRE_THROWS_WITH(infer::run_inference(o), FLAT_CONTAINS(file) && FLAT_CONTAINS("'" + key + "'") &&
                                                       FLAT_CONTAINS(std::string(fault) == "nan" ? "non-finite" : "Long"));
      CHECK(!fs::exists(o.out_dir));
    }
  }
  SECTION("a --three-js folder given explicitly must hold three.js") {
    auto o = good;
    o.viewer = true;
    o.glb = true;
    o.three_js_dir = (s.dir / "no_three").string();
    o.out_dir = (s.dir / "three_out").string();
    REQUIRE_THROWS_WITH(infer::run_inference(o), FLAT_CONTAINS("--three-js " + o.three_js_dir));
    CHECK(!fs::exists(o.out_dir));
  }
}

TEST_CASE("flat_infer: a dolly's novel views get their own depth range (they come closer than the input views)",
          "[infer]") {
  auto s = setup("infer_dolly_depth");
  auto o = options(s, "out");
  o.glb = false;
  o.novel.preset = "dolly";
  const auto summary = infer::run_inference(o);
  INFO("input " << summary.input_depth_range.first << ".." << summary.input_depth_range.second << " m, novel "
                << summary.novel_depth_range.first << ".." << summary.novel_depth_range.second << " m");
  CHECK(summary.input_depth_range.first > 0);
  CHECK(summary.input_depth_range.first < summary.input_depth_range.second);
  // The dolly's closest views see the scene nearer than any input view did:
  // with the input views' range their depth would saturate (all bright).
  CHECK(summary.novel_depth_range.first < summary.input_depth_range.first - 0.01);
  auto j = nlohmann::json::parse(read_file(fs::path(o.out_dir) / "summary.json"));
  CHECK(j.at("depth_display_range_m").at("novel").at(0).get<double>() == Approx(summary.novel_depth_range.first));
}

TEST_CASE("depth display range covers every camera of a trajectory: a dolly's closest views do not saturate",
          "[infer]") {
  // 200 triangles at depths 4..6 in front of the origin, the cameras looking down +z.
  const int64_t n = 200;
  auto z = torch::linspace(4.0, 6.0, n);
  auto centre = torch::stack({torch::zeros({n}), torch::zeros({n}), z}, 1);
  auto offsets = torch::tensor({{0.1f, 0.f, 0.f}, {0.f, 0.1f, 0.f}, {-0.1f, -0.1f, 0.f}});
  primitives::TriangleSoup soup{centre.unsqueeze(1) + offsets.unsqueeze(0), torch::rand({n, 3}), torch::ones({n}),
                                torch::ones({n})};
  auto c2w = torch::eye(4).unsqueeze(0).repeat({2, 1, 1});
  c2w[1][2][3] = 3.0;  // the second camera 3 m closer: depths 1..3
  const camera::Cameras both{torch::tensor({0.5f, 0.5f, 0.5f, 0.5f}).repeat({2, 1}), c2w};
  const camera::Cameras first{both.intrinsics.slice(0, 0, 1), both.c2w.slice(0, 0, 1)};
  const auto one = infer::display_depth_range(primitives::ScenePrimitives::of(soup), first);
  CHECK(one.first == Approx(4.04).margin(0.02));
  const auto all = infer::display_depth_range(primitives::ScenePrimitives::of(soup), both);
  CHECK(all.first == Approx(1.04).margin(0.02));  // the close camera's near end
  CHECK(all.second == Approx(5.96).margin(0.02));  // the far camera's far end
}
