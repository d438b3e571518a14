// Temp file beside the target + fsync + rename: rename() within one folder is
// atomic on POSIX, so readers see either the old file or the complete new one.
#include "flat/core/atomic_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>

#include "flat/core/error.h"

namespace flat {
namespace {

namespace fs = std::filesystem;

std::string errno_text() { return std::strerror(errno); }

// Makes the file's data durable before the rename publishes it.
void fsync_path(const std::string& path, int flags, const std::string& what) {
  int fd = ::open(path.c_str(), flags | O_CLOEXEC);
  if (fd < 0) fail(what + ": cannot open " + path + " to sync it: " + errno_text());
  int rc = ::fsync(fd);
  int err = errno;
  ::close(fd);
  if (rc != 0) fail(what + ": fsync failed on " + path + ": " + std::strerror(err));
}

}  // namespace

AtomicFile::AtomicFile(std::string target, std::string temp_suffix) : target_(std::move(target)) {
  if (target_.empty()) fail("atomic write: empty target path");
  static std::atomic<unsigned long long> counter{0};
  temp_ = target_ + ".tmp." + std::to_string(::getpid()) + "." + std::to_string(counter++) + temp_suffix;
  fs::path parent = fs::path(target_).parent_path();
  if (!parent.empty()) {
    std::error_code ec;
    fs::create_directories(parent, ec);
    if (ec) fail(target_ + ": cannot create folder " + parent.string() + ": " + ec.message());
  }
}

AtomicFile::~AtomicFile() {
  if (committed_) return;
  if (out_.is_open()) out_.close();
  std::error_code ec;
  fs::remove(temp_, ec);  // best effort: never throw from a destructor
}

std::ofstream& AtomicFile::stream() {
  if (committed_) fail(target_ + ": stream() after commit()");
  if (!out_.is_open()) {
    out_.open(temp_, std::ios::binary | std::ios::trunc);
    if (!out_) fail(target_ + ": cannot create temp file " + temp_ + ": " + errno_text());
  }
  return out_;
}

void AtomicFile::commit() {
  if (committed_) fail(target_ + ": commit() called twice");
  if (out_.is_open()) {
    out_.flush();
    bool ok = static_cast<bool>(out_);
    out_.close();
    if (!ok || out_.fail()) fail(target_ + ": writing temp file " + temp_ + " failed (disk full?); target left untouched");
  }
  std::error_code ec;
  if (!fs::is_regular_file(temp_, ec)) {
    fail(target_ + ": nothing was written to temp file " + temp_ + "; target left untouched");
  }
  fsync_path(temp_, O_RDONLY, target_);
  if (std::rename(temp_.c_str(), target_.c_str()) != 0) {
    fail(target_ + ": cannot rename temp file " + temp_ + " over it: " + errno_text());
  }
  committed_ = true;
  // Persist the rename itself; a folder that cannot be synced is not an error.
  fs::path parent = fs::path(target_).parent_path();
  int fd = ::open(parent.empty() ? "." : parent.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd >= 0) {
    ::fsync(fd);
    ::close(fd);
  }
}

void check_output_file(const std::string& path, bool overwrite, const std::string& flag) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) fail(flag + " " + path + ": is a folder; expected a file name");
  if (fs::exists(path, ec) && !overwrite)
    fail(flag + " " + path + ": already exists; pass --overwrite to replace it, or choose another name");
}

void write_file_atomic(const std::string& path, const std::string& bytes) {
  AtomicFile file(path);
  file.stream().write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  file.commit();
}

void write_file_atomic(const std::string& path, const std::function<void(std::ostream&)>& writer) {
  AtomicFile file(path);
  writer(file.stream());
  file.commit();
}

}  // namespace flat
