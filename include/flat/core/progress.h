// Progress for long loops: a live line (rate, ETA, current figures) on a
// terminal; periodic spdlog lines when stdout is not a terminal (CI, clusters).
#pragma once
#include <chrono>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace flat {

class Progress {
 public:
  Progress(std::string label, int64_t total, double log_every_seconds = 10.0);
  ~Progress();  // finishes the line ("done"), or abandons it while an exception unwinds
  // Advance by n and set the figures shown ("loss=0.0123 psnr=21.4").
  void step(int64_t n = 1, const std::vector<std::pair<std::string, double>>& figures = {});
  void finish();
  // Ends the line without claiming success: "stopped at 12/100 after 1m05s".
  void abandon();
  double rate() const;         // items per second so far
  double eta_seconds() const;  // remaining time estimate (infinity while unknown)

  // The arithmetic and text behind the line, pure so that tests need no clock.
  static double eta_for(int64_t done, int64_t total, double elapsed_seconds);
  // Items per minute of a finished run's wall time (its summaries); 0 when no time passed.
  static double per_minute(int64_t done, double elapsed_seconds);
  static std::string format_duration(double seconds);  // "45s", "1m12s", "2h05m", "?"
  // "label  123/1000  12.3 it/s  ETA 1m12s  loss=0.012" (final: "done in 1m21s").
  static std::string format_line(const std::string& label, int64_t done, int64_t total, double elapsed_seconds,
                                 const std::string& figures, bool final);

 private:
  std::string label_;
  int64_t total_, done_ = 0;
  double log_every_;
  bool tty_, finished_ = false;
  std::chrono::steady_clock::time_point start_, last_print_;
  std::string figures_;
  void print(bool final);
};

}  // namespace flat
