// An output folder that appears whole or not at all: everything is written
// into "<target>.incomplete-<pid>" beside the target, and commit() renames it
// into place. A run that fails (an exception, a crash) leaves the target as it
// was; the staging folder is removed on unwinding (after a crash, the next
// StagedDir for the same target removes it).
//
// An existing target is refused at construction (before any work is done)
// unless `overwrite`; then commit() swaps the new folder in and only then
// deletes the old one.
#pragma once
#include <string>

namespace flat {

class StagedDir {
 public:
  // Throws flat::Error naming the path when the target exists (without
  // overwrite) or the staging folder cannot be created (e.g. no permission).
  StagedDir(std::string target, bool overwrite);
  ~StagedDir();  // removes the staging folder unless committed
  StagedDir(const StagedDir&) = delete;
  StagedDir& operator=(const StagedDir&) = delete;

  const std::string& path() const { return staging_; }  // write here
  const std::string& target() const { return target_; }
  std::string file(const std::string& relative) const { return staging_ + "/" + relative; }
  void commit();

 private:
  std::string target_, staging_;
  bool overwrite_ = false, committed_ = false;
};

}  // namespace flat
