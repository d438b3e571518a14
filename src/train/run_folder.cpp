#include "train/run_folder.h"

#include <unistd.h>

#include <filesystem>

#include <spdlog/spdlog.h>

#include "flat/core/error.h"
#include "flat/train/checkpoint.h"

namespace flat::train {
namespace fs = std::filesystem;

namespace {

bool holds_a_run(const std::string& dir) {
  std::error_code ec;
  for (const char* entry : {"config.yaml", "checkpoints", "metrics", "model.safetensors"})
    if (fs::exists(fs::path(dir) / entry, ec)) return true;
  return false;
}

// What --overwrite may replace: a folder that is recognisably a run of
// flat_train (its config.yaml beside at least one of the folders a run
// makes), or an empty one. Anything else may be the user's own files.
bool is_run_folder(const std::string& dir) {
  std::error_code ec;
  if (fs::is_empty(dir, ec) && !ec) return true;
  if (!fs::is_regular_file(fs::path(dir) / "config.yaml", ec)) return false;
  for (const char* sub : {"checkpoints", "logs", "metrics"})
    if (fs::is_directory(fs::path(dir) / sub, ec)) return true;
  return false;
}

}  // namespace

// An --overwrite'd run folder is only replaced by replace_run_folder, once
// the new run has loaded everything.
void check_run_folder(const std::string& dir, StartMode mode) {
  std::error_code ec;
  if (mode == StartMode::fresh && holds_a_run(dir)) {
    const auto n = list_checkpoints(dir + "/checkpoints").size();
    fail("run folder '" + dir + "' already holds a run (" + std::to_string(n) +
         " checkpoint(s)): continue it with --resume " + dir + ", start it over with --overwrite, or choose another "
         "run_dir");
  }
  if (mode == StartMode::overwrite && fs::exists(dir, ec)) {
    FLAT_CHECK(fs::is_directory(dir, ec), "run folder '" + dir + "' exists and is not a folder");
    if (!is_run_folder(dir))
      fail("run folder '" + dir + "' is not a flat_train run folder (no config.yaml beside checkpoints/, logs/ or "
           "metrics/); --overwrite replaces only a run folder, so nothing in it was touched: choose another "
           "run_dir, or move its files away yourself");
  }
}

// Renamed aside first (one rename, so a failure before it left the old run
// whole), then deleted.
void replace_run_folder(const std::string& dir) {
  std::error_code ec;
  if (!fs::exists(dir, ec)) return;
  if (!is_run_folder(dir))  // checked at the start; it may have changed since
    fail("run folder '" + dir + "' is no longer a flat_train run folder; --overwrite left it as it is");
  std::string root = dir;
  while (root.size() > 1 && root.back() == '/') root.pop_back();
  const std::string old = root + ".old-" + std::to_string(::getpid());
  fs::rename(root, old, ec);
  if (ec) fail("run folder '" + dir + "': cannot move the old run aside for --overwrite (" + ec.message() + ")");
  fs::remove_all(old, ec);
  if (ec) spdlog::warn("--overwrite: the old run was moved to {} but cannot be deleted ({})", old, ec.message());
}

// The saved config is what --resume reads back (declared in trainer.h).
TrainConfig load_run_config(const std::string& run_dir, const std::vector<std::string>& overrides,
                            std::string* effective_yaml) {
  const std::string file = run_dir + "/config.yaml";
  std::error_code ec;
  if (!fs::exists(file, ec))
    fail(run_dir + ": no config.yaml; is this a run folder of flat_train? (--resume takes the run folder)");
  std::vector<std::string> all = {"run_dir=" + run_dir};  // the folder may have moved since
  all.insert(all.end(), overrides.begin(), overrides.end());
  auto cfg = config::load<TrainConfig>(file, all);
  if (effective_yaml) *effective_yaml = config::to_yaml(cfg);
  return cfg;
}

}  // namespace flat::train
