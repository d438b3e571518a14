// Logging setup (see include/flat/core/log.h): one default spdlog logger with
// a console sink and, when asked, a file sink. Calling it again replaces the
// logger, so an app can first log to the console and later add the run's file.
#include "flat/core/log.h"

#include <filesystem>
#include <memory>
#include <system_error>
#include <vector>

#include <fstream>

#include <spdlog/sinks/basic_file_sink.h>
#include <spdlog/sinks/ringbuffer_sink.h>
#include <spdlog/sinks/stdout_color_sinks.h>

#include "flat/core/error.h"

namespace flat {
namespace {

spdlog::level::level_enum parse_level(const std::string& level) {
  if (level == "trace") return spdlog::level::trace;
  if (level == "debug") return spdlog::level::debug;
  if (level == "info") return spdlog::level::info;
  if (level == "warn") return spdlog::level::warn;
  if (level == "error") return spdlog::level::err;
  fail("log level '" + level + "': expected one of trace, debug, info, warn, error");
}

// The lines logged while there is no log file yet (a trainer's start-up:
// loading data, the init weights), written into the file when it comes, so
// that the run's log holds the whole session.
std::shared_ptr<spdlog::sinks::ringbuffer_sink_mt>& early_lines() {
  static std::shared_ptr<spdlog::sinks::ringbuffer_sink_mt> ring;
  return ring;
}

}  // namespace

void setup_logging(const std::string& level, const std::string& log_file) {
  const auto lvl = parse_level(level);
  std::vector<spdlog::sink_ptr> sinks;
  // Colours only when stdout is a terminal (spdlog's automatic mode).
  sinks.push_back(std::make_shared<spdlog::sinks::stdout_color_sink_mt>());
  auto& ring = early_lines();
  if (log_file.empty()) {
    if (!ring) ring = std::make_shared<spdlog::sinks::ringbuffer_sink_mt>(2000);
    sinks.push_back(ring);
  } else {
    const auto parent = std::filesystem::path(log_file).parent_path();
    std::error_code ec;
    if (!parent.empty()) std::filesystem::create_directories(parent, ec);
    if (ec) fail(log_file + ": cannot create the log folder (" + ec.message() + ")");
    if (ring) {
      std::ofstream early(log_file, std::ios::app);
      for (const auto& line : ring->last_formatted()) early << line;
      ring.reset();
    }
    try {
      // Append: a resumed run keeps the log of its earlier sessions.
      sinks.push_back(std::make_shared<spdlog::sinks::basic_file_sink_mt>(log_file, /*truncate=*/false));
    } catch (const spdlog::spdlog_ex& e) {
      fail(log_file + ": cannot open the log file (" + e.what() + ")");
    }
  }
  auto logger = std::make_shared<spdlog::logger>("flat", sinks.begin(), sinks.end());
  logger->set_level(lvl);
  logger->set_pattern("[%Y-%m-%d %H:%M:%S.%e] [%^%l%$] %v");
  // Flush on every info line: logs are sparse, and a crash must not eat the last ones.
  logger->flush_on(spdlog::level::info);
  spdlog::set_default_logger(logger);
}

}  // namespace flat
