// Checkpoint folders: written whole or not at all, the newest K kept, read
// back exactly, and refused by name when truncated or of another model.
#include <filesystem>
#include <fstream>

#include <torch/torch.h>

#include "data/data_test_dirs.h"
#include "flat/core/error.h"
#include "flat/train/checkpoint.h"
#include "test_support.h"

namespace fs = std::filesystem;
using namespace flat::train;

namespace {
struct Tiny : torch::nn::Module {
  at::Tensor w, b;
  explicit Tiny(int64_t n) {
    w = register_parameter("w", torch::randn({n, 2}));
    b = register_parameter("b", torch::randn({n}));
  }
};
}  // namespace

TEST_CASE("checkpoints: round trip, newest K kept, leftovers of a crash removed", "[train]") {
  const std::string dir = flat::test::fresh_dir("ckpt_roundtrip").string() + "/checkpoints";
  torch::manual_seed(1);
  Tiny model(3);
  flat::optim::AdamW opt(model.named_parameters().pairs(), {});
  model.w.mutable_grad() = torch::ones_like(model.w);
  opt.step(0.1);
  const ModelSignature sig{"pipeline.model.vae.dim: 3\n"};
  for (int64_t step : {2, 4, 6, 8}) {
    TrainerState s{step, "tiny", 1, 0, "steps: 8\n"};
    save_checkpoint(dir, s, model, sig, opt, 2);
  }
  auto all = list_checkpoints(dir);
  REQUIRE(all.size() == 2);
  CHECK(fs::path(all[0]).filename() == "step_00000006");
  // A crashed write leaves a hidden folder: never listed, removed by latest_checkpoint.
  fs::create_directories(dir + "/.incomplete-step_00000010.123");
  CHECK(fs::path(latest_checkpoint(dir)).filename() == "step_00000008");
  CHECK_FALSE(fs::exists(dir + "/.incomplete-step_00000010.123"));

  const double rng_draw = torch::rand({1}).item<double>();
  auto c = read_checkpoint(latest_checkpoint(dir));
  CHECK(c.state.step == 8);
  CHECK(c.state.skipped_steps == 1);
  CHECK(c.state.config_yaml == "steps: 8\n");
  CHECK(c.signature.yaml == sig.yaml);
  CHECK(at::equal(c.model.at("w"), model.w.detach()));
  CHECK(at::equal(c.optimiser.at("exp_avg.w"), opt.state().at("exp_avg.w")));
  // The generator state was captured before rng_draw: restoring it repeats the draw.
  restore_rng(c.rng, "test");
  CHECK(torch::rand({1}).item<double>() == rng_draw);

  Tiny other(3);
  load_model_weights(other, c.model, c.signature, sig, "test");
  CHECK(at::equal(other.w, model.w));
}

TEST_CASE("checkpoints: truncated files and other models are refused by name", "[train]") {
  const std::string dir = flat::test::fresh_dir("ckpt_bad").string() + "/checkpoints";
  Tiny model(3);
  flat::optim::AdamW opt(model.named_parameters().pairs(), {});
  const ModelSignature sig{"pipeline.model.vae.dim: 3\nheads: independent\n"};
  const std::string written = save_checkpoint(dir, {4, "tiny", 0, 0, ""}, model, sig, opt, 3);
  const std::string file = written + "/model.safetensors";
  fs::resize_file(file, fs::file_size(file) - 7);
  REQUIRE_THROWS_WITH(read_checkpoint(written), FLAT_CONTAINS(file));
  std::ofstream(written + "/trainer.json") << "{\"step\": ";
  REQUIRE_THROWS_WITH(read_checkpoint(written), FLAT_CONTAINS("trainer.json"));
  REQUIRE_THROWS_WITH(read_checkpoint(dir + "/step_00000099"), FLAT_CONTAINS("step_00000099"));

  Tiny wide(5);
  auto tensors = flat::TensorMap{{"w", model.w.detach()}, {"b", model.b.detach()}};
  REQUIRE_THROWS_WITH(load_model_weights(wide, tensors, {"pipeline.model.vae.dim: 3\nheads: independent\n"},
                                         {"pipeline.model.vae.dim: 5\nheads: independent\n"}, "old.safetensors"),
                      FLAT_CONTAINS("pipeline.model.vae.dim: checkpoint 3, this config 5"));
  REQUIRE_THROWS_WITH(resolve_model_file(dir + "/../nowhere"), FLAT_CONTAINS("nowhere"));
}

TEST_CASE("checkpoints: NaN weights are never written; the last good one is never pruned for a worse one",
          "[train]") {
  const std::string dir = flat::test::fresh_dir("ckpt_nan").string() + "/checkpoints";
  torch::manual_seed(2);
  Tiny model(3);
  flat::optim::AdamW opt(model.named_parameters().pairs(), {});
  const ModelSignature sig{"pipeline.model.vae.dim: 3\n"};
  // step 2 good; steps 4 and 6 written while steps were being skipped (consecutive_skips > 0).
  save_checkpoint(dir, {2, "tiny", 0, 0, ""}, model, sig, opt, 1);
  save_checkpoint(dir, {4, "tiny", 2, 2, ""}, model, sig, opt, 1);
  save_checkpoint(dir, {6, "tiny", 4, 4, ""}, model, sig, opt, 1);
  auto all = list_checkpoints(dir);
  REQUIRE(all.size() == 2);
  CHECK(fs::path(all[0]).filename() == "step_00000002");  // the last good one, kept beyond `keep`
  CHECK(fs::path(all[1]).filename() == "step_00000006");
  // A good one written later makes the old good one prunable again.
  save_checkpoint(dir, {8, "tiny", 4, 0, ""}, model, sig, opt, 1);
  all = list_checkpoints(dir);
  REQUIRE(all.size() == 1);
  CHECK(fs::path(all[0]).filename() == "step_00000008");

  {
    torch::NoGradGuard no_grad;
    model.w[0][1] = NAN;
  }
  REQUIRE_THROWS_WITH(save_checkpoint(dir, {10, "tiny", 4, 0, ""}, model, sig, opt, 1),
                      FLAT_CONTAINS("step_00000010: not written") && FLAT_CONTAINS("'w'"));
  CHECK_FALSE(fs::exists(dir + "/step_00000010"));
  all = list_checkpoints(dir);
  REQUIRE(all.size() == 1);
  CHECK(fs::path(all[0]).filename() == "step_00000008");  // nothing pruned either
}

TEST_CASE("checkpoints: resume takes the newest intact one, naming and setting aside the others", "[train]") {
  const std::string dir = flat::test::fresh_dir("ckpt_intact").string() + "/checkpoints";
  Tiny model(3);
  flat::optim::AdamW opt(model.named_parameters().pairs(), {});
  const ModelSignature sig{"pipeline.model.vae.dim: 3\n"};
  CHECK_FALSE(load_newest_intact_checkpoint(dir).has_value());  // no folder: a fresh start
  for (int64_t step : {2, 4, 6}) save_checkpoint(dir, {step, "tiny", 0, 0, ""}, model, sig, opt, 3);
  fs::remove(dir + "/step_00000006/trainer.json");
  const std::string f4 = dir + "/step_00000004/model.safetensors";
  fs::resize_file(f4, fs::file_size(f4) - 3);
  std::vector<std::string> skipped;
  auto c = load_newest_intact_checkpoint(dir, &skipped);
  REQUIRE(c.has_value());
  CHECK(c->state.step == 2);
  REQUIRE(skipped.size() == 2);
  CHECK_THAT(skipped[0], FLAT_CONTAINS("step_00000006/trainer.json: missing"));
  CHECK_THAT(skipped[1], FLAT_CONTAINS(f4));
  CHECK(list_checkpoints(dir).size() == 1);
  int aside = 0;
  for (const auto& e : fs::directory_iterator(dir)) aside += e.path().filename().string().find(".broken-") != std::string::npos;
  CHECK(aside == 2);
  // None intact: an error naming each, and nothing moved.
  const std::string f2 = dir + "/step_00000002/model.safetensors";
  fs::resize_file(f2, fs::file_size(f2) - 3);
  REQUIRE_THROWS_WITH(load_newest_intact_checkpoint(dir), FLAT_CONTAINS("no intact checkpoint") && FLAT_CONTAINS(f2));
  CHECK(fs::exists(dir + "/step_00000002"));
}
