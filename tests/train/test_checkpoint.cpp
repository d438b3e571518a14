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
  AdamW opt(model.named_parameters().pairs(), {});
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
  AdamW opt(model.named_parameters().pairs(), {});
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
