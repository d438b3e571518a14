// One held-out number (issue #44): the trainer's validation and flat_eval
// score the same scenes, windows and views the same way, baselines included,
// with two held-out datasets (the baselines pair scenes within a dataset).
#include <cmath>

#include "flat/eval/evaluation_report.h"
#include "flat/eval/evaluation_run.h"
#include "flat/pipeline/trained_model.h"
#include "flat/train/validation.h"
#include "model_fixtures.h"
#include "train_fixtures.h"

using namespace flat;

TEST_CASE("validation scores the held-out scenes exactly as flat_eval does, per dataset", "[train][validation]") {
  const auto dir = test::fresh_dir("val_vs_eval");
  const std::string model = (dir / "model.safetensors").string();
  test::write_tiny_model(model);
  test::write_scenes_with_latents(dir, {"A/room_a", "A/room_b", "B/room_c", "B/room_d"});

  eval::EvalRunOptions o;
  o.model = model;
  o.datasets = {"A=" + (dir / "A").string(), "B=" + (dir / "B").string()};
  o.out_dir = (dir / "eval").string();
  o.device = "cpu";
  o.settings.max_views = 5;
  o.log_level = "warn";
  eval::run_evaluation(o);
  const auto means = eval::dataset_means(eval::read_results_json(o.out_dir + "/results.json").scores).back();
  REQUIRE(means.scenes == 4);

  auto trained = pipeline::load_trained_model(model);
  pipeline::ScenePipeline pipe(trained.config, trained.decoder);
  auto held = train::held_out_scenes({{(dir / "A").string(), 1.0}, {(dir / "B").string(), 1.0}}, 0, 48, 80, 9);
  REQUIRE(held.scenes.size() == 4);
  CHECK(held.dataset == std::vector<size_t>{0, 0, 1, 1});
  // Swap partners stay within a dataset: a -> b, b -> a, c -> d, d -> c.
  CHECK(*held.swap_partner(0) == 1);
  CHECK(*held.swap_partner(1) == 0);
  CHECK(*held.swap_partner(2) == 3);
  const auto settings = train::validation_settings(5, false);
  held.measure_frames(settings);
  const auto r = train::validate(pipe, held, settings, loss::Lpips{nullptr}, 2);
  INFO("validation " << r.psnr << " flat_eval " << means.psnr);
  CHECK(r.samples == 4);
  CHECK(r.views == 4 * 5);
  CHECK(std::abs(r.psnr - means.psnr) < 1e-4);
  CHECK(std::abs(r.ssim - means.ssim) < 1e-5);
  CHECK(std::abs(r.mean_colour_psnr - means.mean_colour_psnr) < 1e-4);
  CHECK(std::abs(r.dataset_mean_psnr - means.dataset_mean_psnr) < 1e-4);
  CHECK(std::abs(r.swap_psnr - means.swap_psnr) < 1e-4);
  CHECK(std::abs(r.normal_cosine - means.normal_cosine) < 1e-5);
  // The depth measures (the synthetic rooms have exact depth): the same figures, and in val.jsonl's scalars.
  REQUIRE(std::isfinite(means.depth_si_log));
  REQUIRE(std::isfinite(means.planar_roughness));
  CHECK(means.depth_scenes == 4);
  CHECK(std::abs(r.depth_si_log - means.depth_si_log) < 1e-6);
  CHECK(std::abs(r.planar_roughness - means.planar_roughness) < 1e-6);
  const auto scalars = r.scalars();
  auto scalar = [&](const std::string& name) {
    for (const auto& [k, v] : scalars)
      if (k == name) return v;
    return double(NAN);
  };
  CHECK(scalar("val_depth_si_log") == r.depth_si_log);
  CHECK(scalar("val_planar_roughness") == r.planar_roughness);
  CHECK(r.grid.defined());
  CHECK(r.grid.size(1) > 2 * 48);  // two rows (grid_views 2)
  // At most `count` scenes, in name order, dataset by dataset.
  auto two = train::held_out_scenes({{(dir / "A").string(), 1.0}, {(dir / "B").string(), 1.0}}, 3, 48, 80, 9);
  REQUIRE(two.scenes.size() == 3);
  CHECK(two.scenes[2].name == "room_c");
  // A stage whose set the scenes lack: named.
  REQUIRE_THROWS_WITH(train::held_out_scenes({{(dir / "A").string(), 1.0}}, 0, 48, 80, 17),
                      FLAT_CONTAINS("48x80_f17"));
}
