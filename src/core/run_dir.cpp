// Run folders (see include/flat/core/run_dir.h). Creating is idempotent: an
// existing run is resumed, nothing in it is removed.
#include "flat/core/run_dir.h"

#include <filesystem>
#include <system_error>

#include "flat/core/error.h"

namespace flat {
namespace {

void make_folder(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::exists(path, ec) && !fs::is_directory(path, ec))
    fail(path + ": exists and is not a folder; cannot use it in a run folder");
  fs::create_directories(path, ec);
  if (ec) fail(path + ": cannot create run folder (" + ec.message() + ")");
}

}  // namespace

RunDir RunDir::create(const std::string& root) {
  if (root.empty()) fail("run folder: empty path");
  RunDir run{root};
  for (const auto& path : {run.root, run.logs(), run.checkpoints(), run.renders(), run.metrics()}) make_folder(path);
  return run;
}

}  // namespace flat
