// flat_mesh's job end to end on the soup flat_infer decodes from a synthetic
// room with a tiny random-weight decoder: refinement beats the feedforward
// soup on the fitted views, every output is written, and bad inputs fail
// before anything is.
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "flat/infer/inference.h"
#include "flat/infer/mesh_run.h"
#include "model_fixtures.h"
#include "test_support.h"

namespace fs = std::filesystem;
using namespace flat;

namespace {

struct Decoded {
  fs::path dir;
  std::string infer_out, scene, other;  // other: a second room, for the baselines
};

// flat_infer's output for a room of 13 frames, window 0 = frames 0..8.
const Decoded& decoded() {
  static Decoded d = [] {
    Decoded x;
    x.dir = test::scratch_dir("mesh_run");
    const auto model = (x.dir / "model.safetensors").string();
    test::write_tiny_model(model);
    x.scene = (x.dir / "room").string();
    test::write_scene_with_latents(x.scene, 3);
    x.other = (x.dir / "other_room").string();
    test::write_scene_with_latents(x.other, 8);
    infer::InferOptions o;
    o.model = model;
    o.input.scene_dir = x.scene;
    o.out_dir = x.infer_out = (x.dir / "infer").string();
    o.device = "cpu";
    o.novel.preset = "none";
    o.video = o.viewer = o.renders = false;
    o.log_level = "warn";
    infer::run_inference(o);
    return x;
  }();
  return d;
}

infer::MeshRunOptions options(const std::string& out) {
  infer::MeshRunOptions o;
  o.from = decoded().infer_out;
  o.out_dir = (decoded().dir / out).string();
  o.device = "cpu";
  o.refine.steps = 40;
  o.opaque.selection_steps = 10;
  o.opaque.repair_steps = 10;
  o.viewer = false;
  o.log_level = "warn";
  return o;
}

nlohmann::json read_json(const fs::path& p) {
  std::ifstream in(p);
  return nlohmann::json::parse(in);
}

}  // namespace

TEST_CASE("flat_mesh refines the decoded soup, converts it and writes every output", "[infer]") {
  auto o = options("mesh");
  o.baseline_scenes = {decoded().other, decoded().scene};  // its own scene is skipped
  const auto s = infer::run_mesh(o);
  const fs::path out = o.out_dir;
  for (const char* f : {"refined.ply", "mesh.ply", "mesh.obj", "mesh_stats.json", "metrics.json", "summary.json",
                        "mesh.log"})
    CHECK(fs::exists(out / f));
  // The scene folder and window come from flat_infer's summary.json.
  const auto summary = read_json(out / "summary.json");
  CHECK(summary["window"] == 0);
  CHECK(fs::equivalent(summary["scene_dir"].get<std::string>(), decoded().scene));
  // 9 window frames, every 4th from the 2nd held out: 2, 6.
  const auto metrics = read_json(out / "metrics.json");
  CHECK(metrics["views"]["held_out"] == nlohmann::json({2, 6}));
  CHECK(metrics["views"]["fitted"].size() == 7);
  const auto& ff = s.scores.at("feedforward").at("fitted");
  const auto& refined = s.scores.at("refined").at("fitted");
  INFO("feedforward " << ff.psnr << " dB, refined " << refined.psnr << " dB, oracle " << ff.mean_colour_psnr);
  CHECK(refined.psnr > ff.psnr + 3.0);
  CHECK(refined.psnr > refined.mean_colour_psnr);
  // Baselines from the other room: the refined soup scores its own room far
  // above the other room's frames and above that room's image.
  const auto& held = s.scores.at("refined").at("held_out");
  INFO("held-out refined " << held.psnr << ", swap " << held.swap_psnr << ", dataset mean " << held.dataset_mean_psnr);
  CHECK(held.psnr > held.swap_psnr + 3.0);
  CHECK(held.psnr > held.dataset_mean_psnr + 3.0);
  CHECK(metrics["scores"]["mesh"]["held_out"]["swap_psnr"].is_number());
  CHECK(std::isfinite(s.scores.at("mesh").at("held_out").psnr));
  CHECK(std::isfinite(ff.normal_cosine));  // the room has reference normals
  const auto stats = read_json(out / "mesh_stats.json");
  CHECK(stats["faces"].get<int64_t>() > 0);
  CHECK(stats["isolated_faces_pct"].get<double>() == 0.0);
  CHECK_THAT(infer::format_summary(s), FLAT_CONTAINS("refined"));
}

TEST_CASE("flat_mesh: a bad source, scene or window fails before the output folder appears", "[infer]") {
  auto o = options("bad");
  o.from = (decoded().dir / "nowhere").string();
  CHECK_THROWS(infer::run_mesh(o));
  o = options("bad");
  o.window = 5;
  REQUIRE_THROWS_WITH(infer::run_mesh(o), FLAT_CONTAINS("window 5 does not exist"));
  o = options("bad");
  o.refine.loss.lambda_depth = 0.1;
  o.scene_dir = (decoded().dir / "no_scene").string();
  CHECK_THROWS(infer::run_mesh(o));
  CHECK_FALSE(fs::exists(decoded().dir / "bad"));
  // Every triangle pruned: an error that says so, and still no folder.
  o = options("bad");
  o.refine.prune_opacity = 0.9999;
  o.refine.prune_every = 1;
  REQUIRE_THROWS_WITH(infer::run_mesh(o), FLAT_CONTAINS("would remove every triangle"));
  CHECK_FALSE(fs::exists(decoded().dir / "bad"));
}
