// The paper's four progressive stages as a user runs them, at tiny sizes on
// the CPU: the shipped configs/tiny/stage1..4.yaml (their paths moved into a
// scratch folder, steps cut), one set of dataset folders, one flat_latents
// call making every stage's latent set from the configs, each stage starting
// from the one before, the geometry terms active, a SIGKILL in the middle of
// the chain and --resume, then flat_eval on the last stage's held-out set.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "flat/data/scene.h"
#include "flat/eval/evaluation_report.h"
#include "train_fixtures.h"

namespace fs = std::filesystem;
using namespace flat::test;

namespace {

// configs/tiny/stageN.yaml with runs/tiny/ moved to `root`.
std::string stage_config(int n, const std::string& dir, const std::string& root) {
  std::string text = read_file(std::string(FLAT_SOURCE_DIR) + "/configs/tiny/stage" + std::to_string(n) + ".yaml");
  REQUIRE_FALSE(text.empty());
  for (size_t at = text.find("runs/tiny/"); at != std::string::npos; at = text.find("runs/tiny/", at))
    text.replace(at, 10, root + "/"), at += root.size() + 1;
  const std::string path = dir + "/stage" + std::to_string(n) + ".yaml";
  std::ofstream(path) << text;
  return path;
}

std::vector<std::string> short_run(const std::string& config) {
  return {"--config", config,          "--set", "steps=4",        "--set", "checkpoint.every=2",
          "--set",    "validation.every=2", "--set", "validation.scenes=2", "--set", "log.progress_seconds=1",
          "--set",    "threads=1",          "--set", "optim.warmup_steps=1"};
}

}  // namespace

TEST_CASE("the four tiny stages chain on one set of dataset folders, each on its own latent set",
          "[train][chain]") {
  const std::string d = fresh_dir("stage_chain").string(), root = d + "/runs/tiny";
  std::vector<std::string> configs;
  for (int n = 1; n <= 4; ++n) configs.push_back(stage_config(n, d, root));
  const std::string log = d + "/make.log";
  for (auto [name, scenes, seed] : {std::tuple{"train", "3", "5"}, std::tuple{"val", "2", "77"}})
    REQUIRE(run({binary("flat_synth"), "--out", root + "/data/" + name, "--count", scenes, "--seed", seed,
                 "--family", "room", "--frames", "17", "--size", "80x144"},
                log) == 0);
  // One call makes what the four stages need: the shipped configs as they are,
  // with an overlay and a --set pointing their datasets at this folder, as a
  // user points them at theirs.
  const std::string overlay = d + "/my_data.yaml";
  std::ofstream(overlay) << "data: {datasets: [{root: " << root << "/data/train}]}\n";
  std::vector<std::string> latents = {binary("flat_latents"), "--configs"};
  for (int n = 1; n <= 4; ++n)
    latents.push_back(std::string(FLAT_SOURCE_DIR) + "/configs/tiny/stage" + std::to_string(n) + ".yaml");
  latents.insert(latents.end(), {"--overlay", overlay, "--set", "validation.datasets=[{root: " + root + "/data/val}]",
                                 "--random-weights", "--dim", "8", "--seed", "0"});
  const int rc_latents = run(latents, d + "/latents.log");
  INFO(read_file(d + "/latents.log"));
  REQUIRE(rc_latents == 0);
  const auto scene = flat::data::read_scene(root + "/data/val/room_000000");
  CHECK(flat::data::latent_set_list(scene) == "48x80_f9, 48x80_f17, 64x112_f17, 80x144_f17");

  const std::vector<std::string> sets = {"48x80_f9", "48x80_f17", "64x112_f17", "80x144_f17"};
  for (int n = 1; n <= 4; ++n) {
    const std::string run_dir = root + "/stage" + std::to_string(n), out = d + "/stage" + std::to_string(n) + ".log";
    auto args = short_run(configs[size_t(n - 1)]);
    if (n == 1) args.insert(args.end(), {"--set", "init.from=scratch", "--set", "init.path=\"\""});  // no trained VAE here
    if (n == 3) {
      // Killed in the middle of the chain (at step 2's validation), then resumed.
      const int killed = train(args, out, {"FLAT_TEST_SIGNAL_IN_VALIDATION=2"});
      INFO(read_file(out));
      REQUIRE(killed == 128 + 9);
      const int resumed = train({"--resume", run_dir, "--set", "threads=1"}, d + "/stage3_resume.log");
      INFO(read_file(d + "/stage3_resume.log"));
      REQUIRE(resumed == 0);
      CHECK_THAT(read_file(d + "/stage3_resume.log"), FLAT_CONTAINS("resume: "));
    } else {
      const int rc = train(args, out);
      INFO(read_file(out));
      REQUIRE(rc == 0);
    }
    INFO("stage " << n);
    const auto report = nlohmann::json::parse(read_file(run_dir + "/data_report.json"));
    CHECK(report["train"]["latent_set"] == sets[size_t(n - 1)]);
    CHECK(report["train"]["scenes"] == 3);
    CHECK(report["train"]["with_depth"] == 3);
    CHECK(report["train"]["with_normals"] == 3);
    CHECK(report["validation"]["scenes"] == 2);
    CHECK(fs::exists(run_dir + "/best/best.json"));  // the best validation's weights, beside the last
    CHECK(fs::exists(run_dir + "/best/model.safetensors"));
    const auto train_rows = rows(run_dir);
    REQUIRE(train_rows.size() == 4);
    // The geometry terms took part in every step.
    for (const auto& r : train_rows) {
      CHECK(r.contains("depth"));
      CHECK(r.contains("normal"));
    }
    const std::string train_log = read_file(run_dir + "/logs/train.log");
    // The start-up lines (before the run folder existed) are in the run's log too.
    if (n > 1) CHECK_THAT(train_log, FLAT_CONTAINS("init: model weights of the earlier stage from " + root + "/stage" +
                                                   std::to_string(n - 1)));
    CHECK_THAT(train_log, FLAT_CONTAINS("loader: dataset '" + root + "/data/train'"));
    CHECK_THAT(train_log, FLAT_CONTAINS("data: 3 training scenes (3 with depth, 3 with normals), 2 validation scenes"));
    CHECK_THAT(train_log, FLAT_CONTAINS("without latent set " + sets[size_t(n - 1)]));
  }
  CHECK_THAT(read_file(root + "/stage4/logs/train.log"),
             FLAT_CONTAINS("optimiser adamw8bit") && FLAT_CONTAINS("activation checkpointing"));

  // The last stage scored on its held-out set, beside the baselines, with the
  // views the trainer's validation scores (validation.max_views 16): one
  // held-out number, the trainer's last validation and flat_eval's table agree.
  const int rc_eval = run({binary("flat_eval"), "--model", root + "/stage4", "--scenes", "synth=" + root + "/data/val",
                           "--latent-set", "80x144_f17", "--max-views", "16", "--out", d + "/eval", "--device", "cpu"},
                          d + "/eval.log");
  INFO(read_file(d + "/eval.log"));
  REQUIRE(rc_eval == 0);
  const std::string table = read_file(d + "/eval/table.md");
  CHECK_THAT(table, FLAT_CONTAINS("oracle"));
  const auto means = flat::eval::dataset_means(flat::eval::read_results_json(d + "/eval/results.json").scores).back();
  const auto val = rows(root + "/stage4", "val").back();
  REQUIRE(means.scenes == 2);
  std::printf("stage 4: trainer's validation PSNR %.4f dB, flat_eval %.4f dB (oracle %.4f / %.4f, swap %.4f / %.4f)\n",
              val.at("val_psnr").get<double>(), means.psnr, val.at("val_mean_colour_psnr").get<double>(),
              means.mean_colour_psnr, val.at("val_swap_psnr").get<double>(), means.swap_psnr);
  CHECK(std::abs(val.at("val_psnr").get<double>() - means.psnr) < 0.05);
  CHECK(std::abs(val.at("val_ssim").get<double>() - means.ssim) < 1e-3);
  CHECK(std::abs(val.at("val_mean_colour_psnr").get<double>() - means.mean_colour_psnr) < 0.05);
  CHECK(std::abs(val.at("val_dataset_mean_psnr").get<double>() - means.dataset_mean_psnr) < 0.05);
  CHECK(std::abs(val.at("val_swap_psnr").get<double>() - means.swap_psnr) < 0.05);
  CHECK(std::abs(val.at("val_normal_cosine").get<double>() - means.normal_cosine) < 1e-3);
  // Without --latent-set, a scene of four sets is refused naming them.
  const int rc_ambiguous = run({binary("flat_eval"), "--model", root + "/stage4", "--scenes",
                                "synth=" + root + "/data/val", "--out", d + "/eval2", "--device", "cpu"},
                               d + "/eval2.log");
  CHECK(rc_ambiguous != 0);
  CHECK_THAT(read_file(d + "/eval2.log"), FLAT_CONTAINS("--latent-set"));
}
