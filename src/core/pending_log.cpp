// A log file written only on success (include/flat/core/pending_log.h).
#include "flat/core/pending_log.h"

#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>

#include "flat/core/log.h"

namespace flat {
namespace fs = std::filesystem;

void PendingLog::start(const std::string& level, const std::string& log_file) {
  level_ = level;
  final_ = log_file;
  std::error_code ec;
  fs::path dir = fs::temp_directory_path(ec);
  if (ec) dir = "/tmp";
  temp_ = (dir / (fs::path(log_file).filename().string() + "." + std::to_string(::getpid()))).string();
  fs::remove(temp_, ec);
  setup_logging(level, temp_);
}

void PendingLog::keep() {
  if (temp_.empty() || kept_) return;
  spdlog::default_logger()->flush();
  // The work succeeded: a log that cannot be placed is a warning, not a failure.
  {
    std::ifstream in(temp_, std::ios::binary);
    std::ofstream out(final_, std::ios::binary | std::ios::app);
    if (out) out << in.rdbuf();
    if (out) out.flush();
    if (!out) {
      spdlog::warn("{}: cannot append the log there; it stays in {}", final_, temp_);
      kept_ = true;  // (the destructor need not name it again)
      return;
    }
  }
  kept_ = true;
  setup_logging(level_, final_);  // closes the temporary file
  std::error_code ec;
  fs::remove(temp_, ec);
}

PendingLog::~PendingLog() {
  if (temp_.empty() || kept_) return;
  std::cerr << "the log of this run is " << temp_ << " (not written to " << final_
            << ": a failed run leaves its input folders as they were)\n";
}

}  // namespace flat
