// Progress for long loops (see include/flat/core/progress.h): a live line on a
// terminal, periodic spdlog lines elsewhere so that CI and cluster logs stay short.
#include "flat/core/progress.h"

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <exception>
#include <limits>

#include <spdlog/spdlog.h>

namespace flat {
namespace {

using Clock = std::chrono::steady_clock;

double seconds_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

std::string printf_text(const char* format, double x) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), format, x);
  return buf;
}

// "12.3 it/s", or "3.1 s/it" for slow loops where items/s would read 0.3.
std::string rate_text(int64_t done, double elapsed) {
  if (done <= 0 || elapsed <= 0) return "? it/s";
  const double rate = double(done) / elapsed;
  if (rate >= 100) return printf_text("%.0f it/s", rate);
  if (rate >= 1) return printf_text("%.1f it/s", rate);
  return printf_text("%.1f s/it", 1.0 / rate);
}

// A terminal line is redrawn at most this often.
constexpr double kTerminalRefreshSeconds = 0.1;

}  // namespace

Progress::Progress(std::string label, int64_t total, double log_every_seconds)
    : label_(std::move(label)), total_(total), log_every_(log_every_seconds) {
  tty_ = isatty(fileno(stdout)) != 0;
  start_ = last_print_ = Clock::now();
}

Progress::~Progress() {
  try {
    if (std::uncaught_exceptions() > 0) {
      abandon();  // the loop failed: never print "done" for it
    } else {
      finish();
    }
  } catch (...) {
    // a destructor must not throw; losing the last progress line is harmless
  }
}

void Progress::step(int64_t n, const std::vector<std::pair<std::string, double>>& figures) {
  done_ += n;
  if (!figures.empty()) {
    figures_.clear();
    for (const auto& [name, value] : figures)
      figures_ += (figures_.empty() ? "" : " ") + name + "=" + printf_text("%.4g", value);
  }
  if (finished_) return;
  const double since = seconds_between(last_print_, Clock::now());
  if (since >= (tty_ ? kTerminalRefreshSeconds : log_every_)) print(false);
}

void Progress::finish() {
  if (finished_) return;
  finished_ = true;
  print(true);
}

void Progress::abandon() {
  if (finished_) return;
  finished_ = true;
  std::string line = label_ + "  stopped at " + std::to_string(done_);
  if (total_ > 0) line += "/" + std::to_string(total_);
  line += " after " + format_duration(seconds_between(start_, Clock::now()));
  if (tty_) {
    std::fprintf(stdout, "\r%s\x1b[K\n", line.c_str());
    std::fflush(stdout);
  } else {
    spdlog::info("{}", line);
  }
}

double Progress::rate() const {
  const double elapsed = seconds_between(start_, Clock::now());
  return elapsed > 0 ? double(done_) / elapsed : 0.0;
}

double Progress::eta_seconds() const { return eta_for(done_, total_, seconds_between(start_, Clock::now())); }

double Progress::eta_for(int64_t done, int64_t total, double elapsed_seconds) {
  if (total > 0 && done >= total) return 0.0;
  if (total <= 0 || done <= 0 || elapsed_seconds <= 0) return std::numeric_limits<double>::infinity();
  return double(total - done) * elapsed_seconds / double(done);
}

double Progress::per_minute(int64_t done, double elapsed_seconds) {
  return elapsed_seconds > 0 ? double(done) * 60.0 / elapsed_seconds : 0.0;
}

std::string Progress::format_duration(double seconds) {
  if (!std::isfinite(seconds) || seconds < 0) return "?";
  const auto s = static_cast<long long>(std::llround(seconds));
  char buf[64];
  if (s < 60) {
    std::snprintf(buf, sizeof(buf), "%llds", s);
  } else if (s < 3600) {
    std::snprintf(buf, sizeof(buf), "%lldm%02llds", s / 60, s % 60);
  } else {
    std::snprintf(buf, sizeof(buf), "%lldh%02lldm", s / 3600, (s % 3600) / 60);
  }
  return buf;
}

std::string Progress::format_line(const std::string& label, int64_t done, int64_t total, double elapsed_seconds,
                                  const std::string& figures, bool final) {
  std::string line = label + "  " + std::to_string(done);
  if (total > 0) line += "/" + std::to_string(total);
  line += "  " + rate_text(done, elapsed_seconds);
  if (final) {
    line += "  done in " + format_duration(elapsed_seconds);
  } else if (total > 0) {
    line += "  ETA " + format_duration(eta_for(done, total, elapsed_seconds));
  }
  if (!figures.empty()) line += "  " + figures;
  return line;
}

void Progress::print(bool final) {
  const auto now = Clock::now();
  last_print_ = now;
  const std::string line = format_line(label_, done_, total_, seconds_between(start_, now), figures_, final);
  if (tty_) {
    // Carriage return + clear to end of line: the line updates in place.
    std::fprintf(stdout, "\r%s\x1b[K%s", line.c_str(), final ? "\n" : "");
    std::fflush(stdout);
  } else {
    spdlog::info("{}", line);
  }
}

}  // namespace flat
