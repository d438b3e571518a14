#include "flat/core/staged_dir.h"

#include <signal.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>

#include <filesystem>

#include <spdlog/spdlog.h>

#include "flat/core/error.h"

namespace flat {
namespace fs = std::filesystem;

namespace {
constexpr const char* kIncomplete = ".incomplete-";

// Staging folders of earlier runs on the same target that died (their pid is gone).
void remove_stale_staging(const fs::path& target) {
  std::error_code ec;
  const fs::path parent = target.parent_path().empty() ? fs::path(".") : target.parent_path();
  const std::string prefix = target.filename().string() + kIncomplete;
  for (const auto& e : fs::directory_iterator(parent, ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind(prefix, 0) != 0) continue;
    const long pid = std::atol(name.c_str() + prefix.size());
    if (pid > 0 && ::kill(pid_t(pid), 0) == 0) continue;  // another live process writes it
    spdlog::warn("{}: removing '{}', left by a run that did not finish", target.string(), e.path().string());
    fs::remove_all(e.path(), ec);
  }
}
}  // namespace

StagedDir::StagedDir(std::string target, bool overwrite) : target_(std::move(target)), overwrite_(overwrite) {
  FLAT_CHECK(!target_.empty(), "output folder: empty path");
  while (target_.size() > 1 && target_.back() == '/') target_.pop_back();
  std::error_code ec;
  if (fs::exists(target_, ec)) {
    if (!overwrite_) fail(target_ + ": already exists; choose a new output folder or pass --overwrite");
    if (!fs::is_directory(target_, ec)) fail(target_ + ": exists and is not a folder");
  }
  const fs::path parent = fs::path(target_).parent_path();
  if (!parent.empty()) {
    fs::create_directories(parent, ec);
    if (ec) fail(parent.string() + ": cannot create the output's parent folder (" + ec.message() + ")");
  }
  remove_stale_staging(target_);
  staging_ = target_ + kIncomplete + std::to_string(::getpid());
  fs::remove_all(staging_, ec);
  fs::create_directory(staging_, ec);
  if (ec) fail(target_ + ": cannot write the output folder (" + ec.message() + ")");
  // A folder can be creatable yet not writable inside (odd ACLs): check now, not after the work.
  const std::string probe = staging_ + "/.probe";
  FILE* f = std::fopen(probe.c_str(), "w");
  if (!f) {
    fs::remove_all(staging_, ec);
    fail(target_ + ": cannot write the output folder (cannot create files in " + staging_ + ")");
  }
  std::fclose(f);
  fs::remove(probe, ec);
}

StagedDir::~StagedDir() {
  if (committed_) return;
  std::error_code ec;
  fs::remove_all(staging_, ec);
}

void StagedDir::commit() {
  FLAT_CHECK(!committed_, staging_ + ": committed twice");
  std::error_code ec;
  std::string old;
  if (fs::exists(target_, ec)) {
    if (!overwrite_) fail(target_ + ": appeared while this run was writing; the result stays in " + staging_);
    old = target_ + ".old-" + std::to_string(::getpid());
    fs::rename(target_, old, ec);
    if (ec) fail(target_ + ": cannot move the old folder aside (" + ec.message() + ")");
  }
  fs::rename(staging_, target_, ec);
  if (ec) {
    if (!old.empty()) fs::rename(old, target_, ec);
    fail(target_ + ": cannot move the finished output into place (" + ec.message() + "); it stays in " + staging_);
  }
  committed_ = true;
  if (!old.empty()) fs::remove_all(old, ec);
}

}  // namespace flat
