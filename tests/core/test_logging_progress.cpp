// Logging setup (file sink, levels) and the progress reporter's arithmetic and text.
#include <unistd.h>

#include <cmath>
#include <fstream>
#include <limits>
#include <memory>
#include <sstream>
#include <string>

#include <spdlog/sinks/ostream_sink.h>

#include "flat/core/error.h"
#include "flat/core/log.h"
#include "flat/core/progress.h"
#include "test_support.h"

namespace {

std::string read_text(const std::filesystem::path& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

size_t count_of(const std::string& text, const std::string& what) {
  size_t n = 0;
  for (size_t pos = text.find(what); pos != std::string::npos; pos = text.find(what, pos + 1)) ++n;
  return n;
}

// Routes spdlog into a string for the duration of a test.
struct CapturedLog {
  std::ostringstream out;
  std::shared_ptr<spdlog::logger> previous = spdlog::default_logger();
  CapturedLog() {
    auto logger = std::make_shared<spdlog::logger>("capture", std::make_shared<spdlog::sinks::ostream_sink_st>(out));
    logger->set_pattern("%l %v");
    spdlog::set_default_logger(logger);
  }
  ~CapturedLog() { spdlog::set_default_logger(previous); }
};

TEST_CASE("logging: the file sink writes the log file, levels filter, a second setup appends", "[log]") {
  const auto dir = flat::test::scratch_dir("logging");
  const auto file = dir / "run" / "logs" / "flat.log";  // folders do not exist yet
  flat::setup_logging("debug", file.string());
  spdlog::debug("debug line {}", 1);
  spdlog::info("info line {}", 2);
  spdlog::trace("trace line is below the level");
  spdlog::default_logger()->flush();
  std::string text = read_text(file);
  CHECK(text.find("[debug] debug line 1") != std::string::npos);
  CHECK(text.find("[info] info line 2") != std::string::npos);
  CHECK(text.find("trace line") == std::string::npos);

  flat::setup_logging("warn", file.string());  // safe to call again; appends
  spdlog::info("info after warn level");
  spdlog::warn("warn line {}", 3);
  spdlog::default_logger()->flush();
  text = read_text(file);
  CHECK(text.find("info line 2") != std::string::npos);
  CHECK(text.find("info after warn level") == std::string::npos);
  CHECK(text.find("[warning] warn line 3") != std::string::npos);

  flat::setup_logging("info");  // console only: later tests do not write into the scratch file
}

TEST_CASE("logging: an unknown level is an error naming it", "[log]") {
  REQUIRE_THROWS_WITH(flat::setup_logging("verbose"), FLAT_CONTAINS("log level 'verbose'"));
}

TEST_CASE("logging: a log file that cannot be created names its path", "[log]") {
  const auto dir = flat::test::scratch_dir("logging_bad");
  std::ofstream(dir / "blocker") << "a file where a folder should be";
  const auto file = (dir / "blocker" / "flat.log").string();
  REQUIRE_THROWS_WITH(flat::setup_logging("info", file), FLAT_CONTAINS(file));
  flat::setup_logging("info");
}

TEST_CASE("progress: durations read as seconds, minutes or hours", "[progress]") {
  CHECK(flat::Progress::format_duration(0) == "0s");
  CHECK(flat::Progress::format_duration(45.2) == "45s");
  CHECK(flat::Progress::format_duration(72) == "1m12s");
  CHECK(flat::Progress::format_duration(3600 + 5 * 60 + 9) == "1h05m");
  CHECK(flat::Progress::format_duration(std::numeric_limits<double>::infinity()) == "?");
}

TEST_CASE("progress: ETA is remaining items over the rate so far", "[progress]") {
  using flat::Progress;
  CHECK(Progress::eta_for(250, 1000, 10.0) == Approx(30.0));
  CHECK(Progress::eta_for(500, 1000, 20.0) == Approx(20.0));  // same rate, half left: decreasing
  CHECK(Progress::eta_for(1000, 1000, 40.0) == 0.0);
  CHECK(std::isinf(Progress::eta_for(0, 1000, 10.0)));  // no rate yet
  CHECK(std::isinf(Progress::eta_for(10, 0, 10.0)));    // unknown total
}

TEST_CASE("progress: a finished run's items per minute", "[progress]") {
  using flat::Progress;
  CHECK(Progress::per_minute(30, 90.0) == Approx(20.0));
  CHECK(Progress::per_minute(0, 90.0) == 0.0);
  CHECK(Progress::per_minute(30, 0.0) == 0.0);  // no time passed: no rate
}

TEST_CASE("progress: the line shows count, rate, ETA and figures", "[progress]") {
  using flat::Progress;
  CHECK(Progress::format_line("train", 250, 1000, 20.0, "loss=0.012", false) ==
        "train  250/1000  12.5 it/s  ETA 1m00s  loss=0.012");
  CHECK(Progress::format_line("train", 1000, 1000, 20.0, "", true) == "train  1000/1000  50.0 it/s  done in 20s");
  CHECK(Progress::format_line("slow", 2, 10, 6.0, "", false) == "slow  2/10  3.0 s/it  ETA 24s");
  CHECK(Progress::format_line("open", 5000, 0, 2.0, "", false) == "open  5000  2500 it/s");
}

TEST_CASE("progress: figures, rate and ETA of a live reporter", "[progress]") {
  const bool tty = isatty(fileno(stdout)) != 0;
  CapturedLog log;
  {
    flat::Progress p("fit", 10, /*log_every_seconds=*/1e9);  // no periodic line in this test
    for (int i = 0; i < 10; ++i) p.step(1, {{"loss", 0.5 / (i + 1)}, {"psnr", 20.0 + i}});
    CHECK(p.rate() >= 0.0);
    CHECK(p.eta_seconds() == 0.0);  // all done
  }  // the destructor finishes the line
  if (!tty) {
    const std::string text = log.out.str();
    CHECK(count_of(text, "fit  ") == 1);  // only the final line
    CHECK(text.find("fit  10/10") != std::string::npos);
    CHECK(text.find("done in") != std::string::npos);
    CHECK(text.find("loss=0.05 psnr=29") != std::string::npos);
  }
}

TEST_CASE("progress: when not a terminal, a line at most every log_every seconds", "[progress]") {
  if (isatty(fileno(stdout))) return;  // the terminal path redraws one line instead
  CapturedLog log;
  flat::Progress p("often", 3, /*log_every_seconds=*/0.0);
  p.step();
  p.step();
  CHECK(count_of(log.out.str(), "often  ") == 2);
  CHECK(std::isfinite(p.eta_seconds()));
  p.finish();
  p.finish();  // idempotent
  CHECK(count_of(log.out.str(), "often  ") == 3);
  CHECK(log.out.str().find("often  2/3") != std::string::npos);
}

}  // namespace
