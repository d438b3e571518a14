// opacity_shift_calibration: a stage that starts pruning tries lower opacity
// shifts (every opacity raised together) on a few training batches and trains
// with the best; the shift is kept in the run's config and model file, and a
// resumed run keeps it.

#include <ATen/ATen.h>

#include "flat/core/tensor_io.h"
#include "flat/train/opacity_calibration.h"
#include "train_fixtures.h"

using namespace flat::test;

TEST_CASE("reshift_opacities gives the opacities the decoder gives under the other shift", "[train][prune]") {
  const auto x = at::linspace(-8, 8, 101, at::kDouble);  // raw head outputs
  for (double from : {0.0, -1.5})
    for (double to : {0.0, -0.5, -3.0}) {
      const auto decoded = at::sigmoid(x - from).to(at::kFloat);
      const auto expected = at::sigmoid(x - to).to(at::kFloat);
      const auto got = flat::train::reshift_opacities(decoded, from, to);
      // float opacities carry ~1e-7 relative error: the logit amplifies it
      // near 0 and 1, where the sigmoid flattens it again.
      CHECK((got - expected).abs().max().item<double>() < 1e-5);
    }
  const auto c = flat::train::opacity_shift_candidates(-1.0);
  REQUIRE(c.size() == 13);
  CHECK(c.front() == -1.0);
  CHECK(c.back() == -7.0);
}

TEST_CASE("flat_train: opacity_shift_calibration trains a pruning stage with the shift whose renders fit best",
          "[train][prune]") {
  // Threshold 0.9: the fresh model's opacities (about sigmoid(0) = 0.5) are
  // all under it, so uncalibrated steps render nearly nothing; a shift of
  // about -2.5 or lower keeps most of them.
  const std::string d = fresh_dir("opacity_calibration").string();
  const std::string config = write_config(d, 2);
  const std::vector<std::string> args = {"--config", config, "--set", "pipeline.prune_opacity=0.9", "--set",
                                         "opacity_shift_calibration=2", "--set", "validation.every=1000"};
  REQUIRE(train(args, d + "/log.txt") == 0);
  const std::string log = read_file(d + "/log.txt");
  INFO(log);
  REQUIRE(log.find("opacity calibration: 2 training batch(es)") != std::string::npos);
  const auto chosen = log.find("training with pipeline.triangles.opacity_shift ");
  REQUIRE(chosen != std::string::npos);
  const double shift = std::stod(log.substr(chosen + std::string("training with pipeline.triangles.opacity_shift ").size()));
  CHECK(shift <= -2.5);
  // The steps trained with it: they render triangles the uncalibrated
  // threshold removes (5 input frames of 32x48, one triangle per 2x2 pixels).
  const auto r = rows(d + "/run");
  REQUIRE(r.size() == 2);
  CHECK(r[0].at("triangles").get<double>() > 0.5 * 5 * 16 * 24);
  // Kept where inference and resume read it: config.yaml and the model file.
  const std::string saved = read_file(d + "/run/config.yaml");
  CHECK(saved.find("opacity_shift: " + flat::config::to_yaml_scalar(shift)) != std::string::npos);
  flat::Metadata meta;
  flat::load_safetensors(d + "/run/model.safetensors", &meta);
  REQUIRE(meta.count("pipeline_config"));
  CHECK(meta.at("pipeline_config").find("opacity_shift: " + flat::config::to_yaml_scalar(shift)) !=
        std::string::npos);
  // Resumed (two more steps): the same shift, no second calibration.
  REQUIRE(train({"--resume", d + "/run", "--set", "steps=4"}, d + "/resume.txt") == 0);
  const std::string resumed = read_file(d + "/resume.txt");
  INFO(resumed);
  CHECK(resumed.find("opacity calibration") == std::string::npos);
  CHECK(rows(d + "/run").size() == 4);
  // (config.yaml now says steps: 4; the shift is the calibrated one still.)
  CHECK(read_file(d + "/run/config.yaml").find("opacity_shift: " + flat::config::to_yaml_scalar(shift)) !=
        std::string::npos);
}
