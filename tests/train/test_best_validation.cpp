// The best held-out validation kept beside the last, and the warning when a
// validation falls (include/flat/train/best_validation.h).
#include <filesystem>
#include <fstream>

#include "flat/train/best_validation.h"
#include "train_fixtures.h"

namespace fs = std::filesystem;
using namespace flat::test;

namespace {
flat::train::ValidationResult scored(double psnr) {
  flat::train::ValidationResult r;
  r.psnr = psnr;
  r.mean_colour_psnr = 9.0;
  return r;
}
}  // namespace

TEST_CASE("best validation: the best weights are kept, a fall after the warm-up is warned and logged, resume reads "
          "the best back",
          "[train][best]") {
  const std::string run = fresh_dir("best_validation").string();
  int writes = 0;
  std::string last_written;
  auto write = [&](const std::string& path) {
    ++writes;
    last_written = path;
    std::ofstream(path) << "weights " << writes;
  };
  flat::train::BestValidation best(run, 0.5, /*warmup_steps=*/100);
  CHECK(best.record(0, scored(10.0), "model.safetensors", write));
  CHECK(best.record(100, scored(12.0), "model.safetensors", write));
  CHECK(writes == 2);
  CHECK(last_written == run + "/best/model.safetensors");
  // Within 0.5 dB of the best: neither a best nor a fall.
  CHECK_FALSE(best.record(200, scored(11.6), "model.safetensors", write));
  CHECK(best.falls() == 0);
  // 1 dB below the best after the warm-up: a fall, logged with its numbers.
  CHECK_FALSE(best.record(300, scored(11.0), "model.safetensors", write));
  CHECK(best.falls() == 1);
  CHECK(writes == 2);  // the best weights stay those of step 100
  const std::string falls = read_file(run + "/logs/val_falls.jsonl");
  CHECK_THAT(falls, FLAT_CONTAINS("\"step\":300") && FLAT_CONTAINS("\"best_step\":100") &&
                        FLAT_CONTAINS("\"best_psnr\":12.0"));
  CHECK(read_file(run + "/best/model.safetensors") == "weights 2");
  CHECK_THAT(read_file(run + "/best/best.json"), FLAT_CONTAINS("\"step\": 100"));
  // A fall at or before the warm-up's end is not warned about.
  flat::train::BestValidation early(fresh_dir("best_validation_early").string(), 0.5, 100);
  early.record(50, scored(12.0), "model.safetensors", write);
  early.record(100, scored(10.0), "model.safetensors", write);
  CHECK(early.falls() == 0);
  // A resumed run knows the best so far: a lower figure writes nothing.
  flat::train::BestValidation resumed(run, 0.5, 100);
  resumed.resume();
  CHECK(resumed.best_psnr() == 12.0);
  CHECK(resumed.best_step() == 100);
  const int before = writes;
  CHECK_FALSE(resumed.record(400, scored(11.9), "model.safetensors", write));
  CHECK(writes == before);
  CHECK(resumed.record(500, scored(12.5), "model.safetensors", write));
  CHECK(writes == before + 1);
  // A best.json cut short is an error naming it.
  std::ofstream(run + "/best/best.json") << "{\"step\": 1";
  flat::train::BestValidation broken(run, 0.5, 100);
  REQUIRE_THROWS_WITH(broken.resume(), FLAT_CONTAINS("best/best.json"));
}
