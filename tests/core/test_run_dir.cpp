// Run folders: created with every sub-folder, resumed without loss, clear errors.
#include <fstream>
#include <string>

#include "flat/core/error.h"
#include "flat/core/run_dir.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;

TEST_CASE("run_dir: create makes the root and every sub-folder", "[run_dir]") {
  const auto dir = flat::test::scratch_dir("run_dir");
  const auto run = flat::RunDir::create((dir / "a" / "run1").string());
  for (const auto& path : {run.root, run.logs(), run.checkpoints(), run.renders(), run.metrics()})
    CHECK(fs::is_directory(path));
  CHECK(run.config_file() == run.root + "/config.yaml");
  CHECK(run.log_file() == run.root + "/logs/flat.log");

  // Creating again resumes: nothing already there is removed.
  std::ofstream(run.checkpoints() + "/step_100.safetensors") << "x";
  const auto again = flat::RunDir::create(run.root);
  CHECK(fs::exists(again.checkpoints() + "/step_100.safetensors"));
}

TEST_CASE("run_dir: a file in the way is an error naming its path", "[run_dir]") {
  const auto dir = flat::test::scratch_dir("run_dir_bad");
  const auto file_root = (dir / "taken").string();
  std::ofstream(file_root) << "not a folder";
  REQUIRE_THROWS_WITH(flat::RunDir::create(file_root), FLAT_CONTAINS(file_root + ": exists and is not a folder"));

  const auto root = (dir / "run").string();
  fs::create_directories(root);
  std::ofstream(root + "/logs") << "not a folder";
  REQUIRE_THROWS_WITH(flat::RunDir::create(root), FLAT_CONTAINS(root + "/logs: exists and is not a folder"));
  REQUIRE_THROWS_WITH(flat::RunDir::create(""), FLAT_CONTAINS("empty path"));
}

}  // namespace
