// Never leave a half-written output in place of a good one: write to a temp
// file beside the target, then rename over it. If commit() is not reached (an
// exception, a crash), the target is untouched and the temp file is removed.
#pragma once
#include <fstream>
#include <functional>
#include <string>

namespace flat {

class AtomicFile {
 public:
  // Creates parent folders. The temp file is "<target>.tmp.<pid>.<counter>"
  // followed by `temp_suffix` (e.g. ".png", so that libraries that pick the
  // format from the extension, like OpenImageIO, see the real one).
  explicit AtomicFile(std::string target, std::string temp_suffix = {});
  ~AtomicFile();                            // removes the temp file unless committed
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  const std::string& temp_path() const { return temp_; }  // for libraries that write by path (OIIO)
  std::ofstream& stream();                                 // binary stream on temp_path() (opened on first use)
  void commit();                                           // flush, fsync, rename; throws flat::Error

 private:
  std::string target_, temp_;
  std::ofstream out_;
  bool committed_ = false;
};

// Before any work: throws flat::Error naming `path` when it is a folder, or
// exists and `overwrite` is false (`flag` names the option in the message:
// "--out-table FILE: already exists; pass --overwrite to replace it").
void check_output_file(const std::string& path, bool overwrite, const std::string& flag);

// Convenience: write `text` (or bytes) to `path` atomically.
void write_file_atomic(const std::string& path, const std::string& bytes);
void write_file_atomic(const std::string& path, const std::function<void(std::ostream&)>& writer);

}  // namespace flat
