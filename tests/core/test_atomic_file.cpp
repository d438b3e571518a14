// AtomicFile: the target changes only at commit(); an abandoned or failed
// write leaves the old file intact and no temp file behind.
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "support/read_file.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using flat::test::read_file;

size_t count_files(const fs::path& dir) {
  size_t n = 0;
  for (const auto& item : fs::directory_iterator(dir)) n += item.is_regular_file();
  return n;
}

}  // namespace

TEST_CASE("AtomicFile publishes only on commit", "[core][atomic_file]") {
  auto dir = flat::test::scratch_dir("atomic_commit");
  const fs::path target = dir / "out.txt";
  flat::write_file_atomic(target.string(), std::string("old"));
  {
    flat::AtomicFile file(target.string());
    // The temp name: "<target>.tmp.<pid>.<counter>", in the same folder.
    const std::string prefix = target.string() + ".tmp." + std::to_string(::getpid()) + ".";
    CHECK(file.temp_path().rfind(prefix, 0) == 0);
    file.stream() << "new contents";
    file.stream().flush();
    CHECK(fs::exists(file.temp_path()));
    CHECK(read_file(target) == "old");  // not yet
    file.commit();
    CHECK(!fs::exists(file.temp_path()));
  }
  CHECK(read_file(target) == "new contents");
  CHECK(count_files(dir) == 1);
}

TEST_CASE("an abandoned AtomicFile leaves the target and removes its temp file", "[core][atomic_file]") {
  auto dir = flat::test::scratch_dir("atomic_abandon");
  const fs::path target = dir / "model.bin";
  flat::write_file_atomic(target.string(), std::string("good"));
  std::string temp;
  {
    flat::AtomicFile file(target.string());
    temp = file.temp_path();
    file.stream() << "half a file";
  }
  CHECK(!fs::exists(temp));
  CHECK(read_file(target) == "good");
  CHECK(count_files(dir) == 1);

  // A writer that throws halfway: the exception passes through, nothing changes.
  REQUIRE_THROWS_WITH(flat::write_file_atomic(target.string(),
                                              [](std::ostream& out) {
                                                out << "partial";
                                                flat::fail("writer broke");
                                              }),
                      FLAT_CONTAINS("writer broke"));
  CHECK(read_file(target) == "good");
  CHECK(count_files(dir) == 1);
}

TEST_CASE("AtomicFile creates parent folders, keeps a suffix, and names paths in errors", "[core][atomic_file]") {
  auto dir = flat::test::scratch_dir("atomic_folders");
  const fs::path target = dir / "a" / "b" / "c.yaml";
  flat::write_file_atomic(target.string(), [](std::ostream& out) { out << "x: 1\n"; });
  CHECK(read_file(target) == "x: 1\n");

  flat::AtomicFile png((dir / "img.png").string(), ".png");
  CHECK(fs::path(png.temp_path()).extension() == ".png");
  CHECK(fs::path(png.temp_path()).parent_path() == dir);

  // Two writers to the same target get distinct temp files.
  flat::AtomicFile first(target.string()), second(target.string());
  CHECK(first.temp_path() != second.temp_path());

  // commit() without anything written, and renaming over a folder, fail clearly.
  flat::AtomicFile nothing((dir / "nothing.txt").string());
  REQUIRE_THROWS_WITH(nothing.commit(), FLAT_CONTAINS("nothing was written"));
  fs::create_directories(dir / "folder");
  REQUIRE_THROWS_WITH(flat::write_file_atomic((dir / "folder").string(), std::string("x")),
                      FLAT_CONTAINS("cannot rename") && FLAT_CONTAINS("folder"));
  CHECK(fs::is_directory(dir / "folder"));

  // A parent that is a file cannot become a folder.
  REQUIRE_THROWS_WITH(flat::AtomicFile((target / "below").string()), FLAT_CONTAINS("cannot create folder"));
}
