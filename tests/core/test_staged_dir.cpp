// StagedDir: an output folder appears whole or not at all.
#include <filesystem>
#include <fstream>

#include "flat/core/staged_dir.h"
#include "support/read_file.h"
#include "test_support.h"

namespace fs = std::filesystem;
using flat::test::read_file;

namespace {
}  // namespace

TEST_CASE("StagedDir: nothing at the target until commit; a failure leaves nothing", "[core]") {
  const auto dir = flat::test::scratch_dir("staged_dir");
  const auto target = dir / "out";
  {
    flat::StagedDir s(target.string(), false);
    std::ofstream(s.file("a.txt")) << "new";
    CHECK(!fs::exists(target));
    s.commit();
  }
  CHECK(read_file(target / "a.txt") == "new");
  // Exists: refused without overwrite, before any work.
  REQUIRE_THROWS_WITH(flat::StagedDir(target.string(), false), FLAT_CONTAINS("already exists"));
  // Overwrite, but the work fails: the old folder stays, the staging folder goes.
  try {
    flat::StagedDir s(target.string(), true);
    std::ofstream(s.file("a.txt")) << "half";
    throw std::runtime_error("work failed");
  } catch (const std::runtime_error&) {
  }
  CHECK(read_file(target / "a.txt") == "new");
  int entries = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir)) ++entries;
  CHECK(entries == 1);
  // Overwrite that succeeds replaces the folder whole (old files do not linger).
  {
    flat::StagedDir s(target.string(), true);
    std::ofstream(s.file("b.txt")) << "b";
    s.commit();
  }
  CHECK(!fs::exists(target / "a.txt"));
  CHECK(read_file(target / "b.txt") == "b");
  // A staging folder left by a dead process is cleared by the next run.
  fs::create_directories(dir / "x.incomplete-999999999");
  { flat::StagedDir s((dir / "x").string(), false); }
  CHECK(!fs::exists(dir / "x.incomplete-999999999"));
  // A parent that is a file: a clear error naming the path.
  std::ofstream(dir / "file") << "x";
  REQUIRE_THROWS_WITH(flat::StagedDir((dir / "file" / "out").string(), false), FLAT_CONTAINS("file"));
}
