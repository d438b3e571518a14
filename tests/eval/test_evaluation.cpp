// flat_eval: the 3DGS SSIM convention, view selection, means and tables, and
// a whole resumable run over synthetic scenes with a failing one.
#include <filesystem>
#include <fstream>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "flat/core/tensor_io.h"
#include "flat/eval/evaluation_report.h"
#include "flat/eval/evaluation_run.h"
#include "flat/eval/image_metrics.h"
#include "model_fixtures.h"
#include "support/read_file.h"
#include "test_support.h"

namespace fs = std::filesystem;
using flat::test::read_file;
using namespace flat;

namespace {

// flat_eval of `model` over `datasets` (NAME=FOLDER) into `out`, on the CPU, logging warnings only.
eval::EvalRunOptions eval_options(const std::string& model, std::vector<std::string> datasets, const fs::path& out) {
  eval::EvalRunOptions o;
  o.model = model;
  o.datasets = std::move(datasets);
  o.out_dir = out.string();
  o.device = "cpu";
  o.log_level = "warn";
  return o;
}

eval::SceneScore score(const std::string& dataset, const std::string& scene, double psnr, double cosine,
                       bool ok = true) {
  eval::SceneScore s;
  s.dataset = dataset;
  s.scene = scene;
  s.ok = ok;
  s.views = 4;
  if (!ok) {
    s.error = "broken";
    return s;
  }
  s.psnr = psnr;
  s.ssim = 0.5;
  if (std::isfinite(cosine)) {
    s.normal_cosine = cosine;
    s.normal_l1 = 1 - cosine;
    s.normal_pixels = 10;
  }
  return s;
}

}  // namespace

// Reference: the 3DGS repositories' formula re-computed in float64 with
// PyTorch (2D Gaussian window 11, sigma 1.5, conv2d padding 5, groups = C,
// C1 = 0.01^2, C2 = 0.03^2, mean over C,H,W) on the patterns of test_metrics.cpp.
TEST_CASE("SSIM, 3DGS convention: zero padding and whole-image mean", "[eval]") {
  const int64_t V = 2, C = 3, H = 24, W = 32;
  auto x = at::arange(W, at::kDouble).view({1, 1, 1, W});
  auto y = at::arange(H, at::kDouble).view({1, 1, H, 1});
  auto c = at::arange(C, at::kDouble).view({1, C, 1, 1});
  auto v = at::arange(V, at::kDouble).view({V, 1, 1, 1});
  auto a = (0.5 + 0.4 * at::sin(0.37 * x + 0.23 * y + 1.1 * c + 0.5 * v)).expand({V, C, H, W}).contiguous();
  auto b = (0.5 + 0.3 * at::cos(0.21 * x - 0.29 * y + 0.7 * c) + 0.15 * at::sin(0.05 * x * y + c + v))
               .expand({V, C, H, W}).contiguous();
  auto b2 = (a + 0.1 * at::sin(1.7 * x) * at::cos(2.3 * y)).contiguous();
  auto s = eval::ssim(a, b, eval::SsimConvention::gaussian_zero_pad);
  CHECK(s[0].item<double>() == Approx(0.20100655385009436).epsilon(1e-9));
  CHECK(s[1].item<double>() == Approx(0.22151802930850387).epsilon(1e-9));
  auto s2 = eval::ssim(a, b2, eval::SsimConvention::gaussian_zero_pad);
  CHECK(s2[0].item<double>() == Approx(0.9563204876750093).epsilon(1e-10));
  CHECK(s2[1].item<double>() == Approx(0.9560512101501669).epsilon(1e-10));
  // The conventions differ on the same images (why tables must say which).
  CHECK(std::abs(eval::ssim(a, b, eval::SsimConvention::skimage)[0].item<double>() - s[0].item<double>()) > 0.05);
  CHECK(eval::parse_ssim_convention("3dgs") == eval::SsimConvention::gaussian_zero_pad);
  REQUIRE_THROWS_WITH(eval::parse_ssim_convention("ms-ssim"), FLAT_CONTAINS("ms-ssim"));
}

TEST_CASE("evaluation views: scene, window and unseen frames, evenly subsampled", "[eval]") {
  data::Scene scene;
  scene.dir = "/x/room";
  scene.frames.resize(20);
  scene.latents.file = "latents.safetensors";
  scene.latents.windows = {{4, 9}};
  eval::EvalSettings s;
  CHECK(eval::evaluation_views(scene, s).size() == 20);
  s.views = "window";
  auto w = eval::evaluation_views(scene, s);
  CHECK(w == std::vector<int64_t>{4, 5, 6, 7, 8, 9, 10, 11, 12});
  s.views = "unseen";
  auto u = eval::evaluation_views(scene, s);
  CHECK(u.size() == 11);
  CHECK(u.front() == 0);
  CHECK(u.back() == 19);
  s.views = "scene";
  s.max_views = 5;
  CHECK(eval::evaluation_views(scene, s) == std::vector<int64_t>{0, 5, 10, 14, 19});
  s.window = 3;
  REQUIRE_THROWS_WITH(eval::evaluation_views(scene, s), FLAT_CONTAINS("window 3"));
}

TEST_CASE("means per dataset skip failures and scenes without normals; the table says how many", "[eval]") {
  eval::EvalResults r;
  r.name = "ours";
  r.scores = {score("RE10K", "a", 20, 0.8), score("RE10K", "b", 22, NAN), score("RE10K", "c", 0, 0, false),
              score("DL3DV", "d", 18, 0.6)};
  // Depth figures where a scene has reference depth (a and d; b has none).
  r.scores[0].depth_si_log = 0.1, r.scores[0].planar_roughness = 0.02, r.scores[0].planar_pixels = 50;
  r.scores[3].depth_si_log = 0.3, r.scores[3].planar_roughness = 0.04, r.scores[3].planar_pixels = 70;
  auto m = eval::dataset_means(r.scores);
  REQUIRE(m.size() == 3);
  CHECK(m[0].dataset == "RE10K");
  CHECK(m[0].scenes == 2);
  CHECK(m[0].failed == 1);
  CHECK(m[0].psnr == Approx(21.0));
  CHECK(m[0].normal_cosine == Approx(0.8));  // only scene a has normals
  CHECK(m[1].psnr == Approx(18.0));
  CHECK(m[2].dataset.empty());
  CHECK(m[2].normal_cosine == Approx(0.7));  // a and d
  CHECK(std::isnan(m[2].lpips));
  CHECK(m[0].depth_si_log == Approx(0.1));  // b has no depth: not a 0 in the mean
  CHECK(m[2].depth_si_log == Approx(0.2));
  CHECK(m[2].planar_roughness == Approx(0.03));
  CHECK(m[2].depth_scenes == 2);
  auto table = eval::table1_markdown({r});
  CHECK(table.find("RE10K PSNR") < table.find("DL3DV PSNR"));
  CHECK(table.find("| Geometry L1 ↓ | Geometry Cosine ↑ | Depth SI-log ↓ | Planar roughness ↓ | Scenes |") !=
        std::string::npos);
  CHECK(table.find("| ours | 21.00 | 0.500 | – | 18.00 | 0.500 | – | 0.300 | 0.700 | 0.200 | 0.0300 | 3/4 |") !=
        std::string::npos);
  CHECK(table.find("scikit-image") != std::string::npos);
  CHECK(table.find("Planar roughness (texture leaking into depth)") != std::string::npos);
  auto csv = eval::results_csv(r);
  CHECK(std::count(csv.begin(), csv.end(), '\n') == 5);
  CHECK(csv.find("RE10K,c,failed") != std::string::npos);
  CHECK(csv.find(",normal_pixels,depth_si_log,planar_roughness,planar_pixels,") != std::string::npos);
  CHECK(csv.find(",10,0.1,0.02,50,") != std::string::npos);  // scene a's normal pixels, then its depth figures
  // JSON round trip keeps NaN as null -> NaN.
  auto back = eval::score_from_json(eval::score_to_json(r.scores[1]));
  CHECK(std::isnan(back.normal_cosine));
  CHECK(std::isnan(back.depth_si_log));
  CHECK(std::isnan(back.planar_roughness));
  CHECK(eval::score_to_json(r.scores[1]).at("depth_si_log").is_null());
  CHECK(back.psnr == 22);
  auto a = eval::score_from_json(eval::score_to_json(r.scores[0]));
  CHECK(a.depth_si_log == 0.1);
  CHECK(a.planar_roughness == 0.02);
  CHECK(a.planar_pixels == 50);
  // Results written before the depth measures read back without them.
  auto old = eval::score_to_json(r.scores[0]);
  old.erase("depth_si_log");
  old.erase("planar_roughness");
  CHECK(std::isnan(eval::score_from_json(old).depth_si_log));
  CHECK(std::isnan(eval::score_from_json(old).planar_roughness));
  auto j = eval::results_json(r);
  CHECK(j.at("means").back().at("planar_roughness").get<double>() == Approx(0.03));
}

TEST_CASE("runs over seeds: one row per ablation, mean and spread beside the baselines", "[eval]") {
  CHECK(eval::seed_group("three_offsets seed 1") == "three_offsets");
  CHECK(eval::seed_group("stage1").empty());
  CHECK(eval::seed_group("a seed x").empty());
  auto run = [](const std::string& name, double psnr) {
    eval::EvalResults r;
    r.name = name;
    r.scores = {score("rooms", "a", psnr, 0.8), score("rooms", "b", psnr + 2, 0.6)};
    return r;
  };
  CHECK(eval::seeds_markdown({run("paper seed 0", 20), run("ts seed 0", 18)}).empty());  // no row has two seeds
  auto t = eval::seeds_markdown({run("paper seed 0", 20), run("paper seed 1", 23), run("ts seed 0", 18)});
  CHECK(t.find("| paper | 2 | 22.50 ± 3.00 |") != std::string::npos);
  CHECK(t.find("| ts | 1 | 19.00 |") != std::string::npos);
  CHECK(t.find("spread") != std::string::npos);
}

TEST_CASE("flat_eval over two datasets: failures listed, resumable, settings guarded, --compare", "[eval]") {
  const auto dir = test::scratch_dir("eval_run");
  const std::string model = (dir / "model.safetensors").string();
  test::write_tiny_model(model);
  test::write_scenes_with_latents(dir, {"setA/room_a", "setA/room_b", "setB/room_c", "setB/room_broken"});
  // A broken scene: its latents file is gone.
  fs::remove(dir / "setB/room_broken/latents_48x80_f9.safetensors");

  auto o = eval_options(model, {"A=" + (dir / "setA").string(), "B=" + (dir / "setB").string()}, dir / "out");
  o.name = "tiny";
  o.settings.max_views = 4;
  auto s = eval::run_evaluation(o);
  CHECK(s.scenes == 4);
  CHECK(s.scored == 3);
  CHECK(s.failed == 1);
  CHECK(s.reused == 0);
  auto results = eval::read_results_json(o.out_dir + "/results.json");
  REQUIRE(results.scores.size() == 4);
  for (const auto& sc : results.scores) {
    if (sc.scene == "room_broken") {
      CHECK(!sc.ok);
      CHECK(sc.error.find("latents_48x80_f9.safetensors") != std::string::npos);
    } else {
      CHECK(sc.ok);
      CHECK(sc.views == 4);
      CHECK(std::isfinite(sc.psnr));
      CHECK(sc.normal_pixels >= 0);
      // The synthetic rooms have exact depth: both depth figures are measured.
      CHECK(std::isfinite(sc.depth_si_log));
      CHECK(sc.planar_pixels > 0);
      CHECK(std::isfinite(sc.planar_roughness));
    }
  }
  CHECK(s.table.find("3/4") != std::string::npos);
  // The table and results.json say which triangles were rendered (flat_infer exports those of its --prune-opacity).
  CHECK(s.table.find("Rendered triangles: opacity at or above 0.000") != std::string::npos);
  CHECK(eval::read_results_json(o.out_dir + "/results.json").prune_opacity == 0.0);
  CHECK(fs::exists(fs::path(o.out_dir) / "scenes.csv"));
  CHECK(fs::exists(fs::path(o.out_dir) / "table.md"));

  // Resume: the scored scenes are reused (their files untouched), the failed one is tried again.
  const std::string a_score = read_file(fs::path(o.out_dir) / "scores/A/room_a.json");
  auto again = eval::run_evaluation(o);
  CHECK(again.reused == 3);
  CHECK(again.failed == 1);
  CHECK(read_file(fs::path(o.out_dir) / "scores/A/room_a.json") == a_score);
  // The same model file spelled another way is the same model.
  auto spelled = o;
  spelled.model = (dir / "." / "model.safetensors").string();
  CHECK(eval::run_evaluation(spelled).reused == 3);

  // Other settings into the same folder: refused unless --redo, saying what differs.
  auto other = o;
  other.settings.max_views = 2;
  REQUIRE_THROWS_WITH(eval::run_evaluation(other), FLAT_CONTAINS("--redo") && FLAT_CONTAINS("max_views=2"));
  other.redo = true;
  other.out_dir = o.out_dir;
  auto redone = eval::run_evaluation(other);
  CHECK(redone.reused == 0);
  CHECK(redone.scored == 3);

  // --compare two runs side by side.
  auto second = o;
  second.out_dir = (dir / "out2").string();
  second.name = "tiny-3dgs-ssim";
  second.settings.ssim = eval::SsimConvention::gaussian_zero_pad;
  eval::run_evaluation(second);
  auto table = eval::compare_runs({o.out_dir, second.out_dir});
  CHECK(table.find("| tiny |") != std::string::npos);
  CHECK(table.find("| tiny-3dgs-ssim |") != std::string::npos);
  CHECK(table.find("different SSIM conventions") != std::string::npos);

  // A dataset path that does not exist fails before anything is written.
  auto bad = o;
  bad.datasets = {"C=" + (dir / "nowhere").string()};
  bad.out_dir = (dir / "out_bad").string();
  REQUIRE_THROWS_WITH(eval::run_evaluation(bad), FLAT_CONTAINS("nowhere"));
  CHECK(!fs::exists(bad.out_dir));
}

// The swap baseline must be able to expose a model that ignores its input:
// one whose output is the same for every scene scores its swap exactly as its
// own PSNR (a cyclic pairing permutes the same terms), while one whose output
// depends on the scene does not.
TEST_CASE("flat_eval baselines: a constant model's swap score equals its own; provenance is in every output",
          "[eval]") {
  const auto dir = test::scratch_dir("eval_baselines");
  for (int i = 0; i < 3; ++i)
    test::write_scene_with_latents((dir / ("set/room_" + std::to_string(i))).string(), uint64_t(10 + i));
  // The constant model: every head weight and bias zero, so every triangle is
  // grey (sigmoid(0) = 0.5), rendered over a grey background: 0.5 everywhere.
  const std::string constant = (dir / "constant.safetensors").string();
  test::write_tiny_model(constant);
  {
    Metadata meta;
    auto tensors = load_safetensors(constant, &meta);
    int zeroed = 0;
    for (auto& [name, t] : tensors)
      if (name.rfind("heads.", 0) == 0) t.zero_(), ++zeroed;
    REQUIRE(zeroed > 0);
    save_safetensors(constant, tensors, meta);
  }
  const std::string varying = (dir / "varying.safetensors").string();
  test::write_tiny_model(varying, 8, 7);

  auto evaluate = [&](const std::string& model, const std::string& out) {
    auto o = eval_options(model, {"synth=" + (dir / "set").string()}, dir / out);
    o.overrides = {"raster.background=[0.5, 0.5, 0.5]"};
    o.settings.max_views = 5;
    auto s = eval::run_evaluation(o);
    REQUIRE(s.scored == 3);
    return eval::dataset_means(eval::read_results_json(o.out_dir + "/results.json").scores).back();
  };
  const auto c = evaluate(constant, "out_constant");
  INFO("constant model: PSNR " << c.psnr << ", swap " << c.swap_psnr << ", dataset mean " << c.dataset_mean_psnr
                               << ", mean colour " << c.mean_colour_psnr);
  REQUIRE(std::isfinite(c.swap_psnr));
  CHECK(c.swap_psnr == Approx(c.psnr).epsilon(1e-5));
  CHECK(std::isfinite(c.dataset_mean_psnr));
  CHECK(c.mean_colour_psnr > c.psnr);  // a grey image is no better than each view's own colour
  const auto v = evaluate(varying, "out_varying");
  INFO("varying model: PSNR " << v.psnr << ", swap " << v.swap_psnr);
  CHECK(std::abs(v.swap_psnr - v.psnr) > 1e-3);

  // Provenance: the fixtures' latents are random, and every output says so.
  CHECK(c.random_latent_scenes == 3);
  const std::string table = read_file(dir / "out_constant/table.md");
  CHECK(table.find("RANDOM-ENCODER LATENTS") != std::string::npos);
  CHECK(table.find("↳ swap") != std::string::npos);
  const auto json = nlohmann::json::parse(read_file(dir / "out_constant/results.json"));
  CHECK(json.at("latent_encoder") == "random");
  CHECK(json.at("scenes")[0].at("swap_scene") == "room_1");
}

TEST_CASE("flat_eval: a model with a NaN weight is named at load, not blamed on every scene", "[eval]") {
  const auto dir = test::scratch_dir("eval_nan_model");
  const std::string good = (dir / "model.safetensors").string(), model = (dir / "nan_model.safetensors").string();
  test::write_tiny_model(good);
  test::write_scene_with_latents((dir / "set/room_a").string(), 1);
  Metadata meta;
  auto tensors = load_safetensors(good, &meta);
  const std::string key = tensors.begin()->first;
  auto t = tensors.at(key).clone();
  t.view(-1)[0] = NAN;
  tensors[key] = t;
  save_safetensors(model, tensors, meta);
  auto o = eval_options(model, {"S=" + (dir / "set").string()}, dir / "out");
  REQUIRE_THROWS_WITH(eval::run_evaluation(o), FLAT_CONTAINS(model + ": weight '" + key + "'") &&
                                                   FLAT_CONTAINS("non-finite"));
  CHECK(!fs::exists(o.out_dir));
}

TEST_CASE("flat_eval's progress line shows the running mean PSNR, not the last scene's", "[eval]") {
  const auto dir = test::scratch_dir("eval_progress");
  const std::string model = (dir / "model.safetensors").string();
  test::write_tiny_model(model);
  for (int i = 0; i < 3; ++i) test::write_scene_with_latents((dir / ("set/room_" + std::to_string(i))).string(), 10 + i);
  auto o = eval_options(model, {"S=" + (dir / "set").string()}, dir / "out");
  o.name = "tiny";
  o.settings.max_views = 4;
  o.log_level = "info";  // the progress lines go to eval.log (not a terminal here)
  eval::run_evaluation(o);
  const auto results = eval::read_results_json(o.out_dir + "/results.json");
  REQUIRE(results.scores.size() == 3);
  double sum = 0;
  for (const auto& sc : results.scores) {
    REQUIRE(sc.ok);
    sum += sc.psnr;
  }
  const double mean = sum / 3, last = results.scores.back().psnr;
  REQUIRE(std::abs(mean - last) > 1e-2 * std::abs(mean));  // the scenes differ enough to tell the two apart
  // The final progress line (3/3): "... mean psnr=<%.4g> ...".
  std::ifstream log(o.out_dir + "/eval.log");
  std::string line, final_line;
  while (std::getline(log, line))
    if (line.find("flat_eval") != std::string::npos && line.find("mean psnr=") != std::string::npos) final_line = line;
  INFO(final_line);
  REQUIRE(!final_line.empty());
  const double shown = std::stod(final_line.substr(final_line.find("mean psnr=") + 10));
  CHECK(std::abs(shown - mean) <= 1e-3 * std::abs(mean));
}
