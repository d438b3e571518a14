// prune_warmup_steps: the training renders' pruning threshold rises from 0 to
// pipeline.prune_opacity, so a stage that starts pruning (stage 4) keeps the
// previous stage's soft triangles (and their gradients) at first.
#include "flat/train/train_step.h"
#include "train_fixtures.h"

using namespace flat::test;
using flat::train::training_prune_opacity;

TEST_CASE("the training prune threshold rises linearly over prune_warmup_steps", "[train][prune]") {
  CHECK(training_prune_opacity(0.4, 0, 0) == 0.4);  // no warm-up: the full threshold from step 0
  CHECK(training_prune_opacity(0.4, 100, 0) == 0.0);
  CHECK(training_prune_opacity(0.4, 100, 25) == Approx(0.1));
  CHECK(training_prune_opacity(0.4, 100, 100) == 0.4);
  CHECK(training_prune_opacity(0.4, 100, 5000) == 0.4);
}

TEST_CASE("flat_train: with prune_warmup_steps the first steps render the triangles that full pruning removes",
          "[train][prune]") {
  // A threshold no fresh triangle reaches: without the warm-up every step
  // renders (almost) nothing; with it, step 0 renders every triangle.
  // Each run: the triangles of its training renders, then its step-0 validation PSNR.
  auto triangles = [](const std::string& name, const std::string& warmup) {
    const std::string d = fresh_dir("prune_warmup_" + name).string();
    const int rc = train({"--config", write_config(d, 3), "--set", "pipeline.prune_opacity=0.99", "--set",
                          "prune_warmup_steps=" + warmup, "--set", "validation.every=1000"},
                         d + "/log.txt");
    INFO(read_file(d + "/log.txt"));
    REQUIRE(rc == 0);
    std::vector<double> t;
    for (const auto& r : rows(d + "/run")) t.push_back(r.at("triangles").get<double>());
    const auto val = rows(d + "/run", "val");
    REQUIRE(!val.empty());
    REQUIRE(val.front().at("step").get<int64_t>() == 0);
    t.push_back(val.front().at("val_psnr").get<double>());
    return t;
  };
  auto full = triangles("off", "0"), ramped = triangles("on", "1000");
  // Validation prunes at the full threshold, warm-up or not: the same model at
  // step 0 scores the same (with the warm-up's threshold, 0, it would render
  // every triangle and score otherwise).
  const double full_val = full.back(), ramped_val = ramped.back();
  full.pop_back();
  ramped.pop_back();
  CHECK(ramped_val == Approx(full_val).margin(1e-9));
  REQUIRE(full.size() == 3);
  REQUIRE(ramped.size() == 3);
  // 5 input frames of 32x48, one triangle per 2x2 pixels, 2 target views' scene = 1 scene.
  const double all = 5.0 * 16 * 24;
  CHECK(ramped[0] == all);
  CHECK(full[0] < 0.01 * all);
  for (size_t i = 0; i < 3; ++i) CHECK(ramped[i] > full[i]);
}
