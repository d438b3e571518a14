#include "train/stop_signals.h"

#include <atomic>
#include <csignal>
#include <cstdlib>
#include <ctime>
#include <string>

#include "flat/train/trainer.h"

namespace flat::train {

namespace {

// The first SIGINT/SIGTERM asks the loop to stop after the current step and
// write a checkpoint; a second one ends the process at once (default action).
// One request often arrives twice: coreutils `timeout` signals the command
// and then its process group, a scheduler signals every process of a job
// step and a terminal its process group, a launcher (flat_train --nproc,
// torchrun) forwards what its rank also got directly. A repeat within a
// second is therefore the same request; a later one still ends the process.
// (Before this, a single-process run under `timeout` lost its checkpoint
// whenever the two copies arrived apart: GPU recipe, 2026-11-26.)
std::atomic<int> g_stop_signal{0};
std::atomic<int64_t> g_first_signal_ms{0};

int64_t monotonic_ms() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);  // async-signal-safe
  return int64_t(ts.tv_sec) * 1000 + ts.tv_nsec / 1000000;
}

extern "C" void on_stop_signal(int sig) {
  if (g_stop_signal.load() == 0) {
    g_first_signal_ms.store(monotonic_ms());
    g_stop_signal.store(sig);
    return;
  }
  if (monotonic_ms() - g_first_signal_ms.load() < 1000) return;
  std::signal(sig, SIG_DFL);
  std::raise(sig);
}

}  // namespace

// SIGHUP (a closed terminal or SSH session) is a stop request too.
StopSignals::StopSignals() {
  g_stop_signal.store(0);
  old_int_ = std::signal(SIGINT, on_stop_signal);
  old_term_ = std::signal(SIGTERM, on_stop_signal);
  old_hup_ = std::signal(SIGHUP, on_stop_signal);
}

StopSignals::~StopSignals() {
  std::signal(SIGINT, old_int_);
  std::signal(SIGTERM, old_term_);
  std::signal(SIGHUP, old_hup_);
}

int stop_signal_requested() { return g_stop_signal.load(); }

// "<step>" raises SIGKILL, "<step>:<signal>" that signal.
void raise_test_signal_in_validation(int64_t step) {
  const char* v = std::getenv(kSignalInValidationEnv);
  if (!v) return;
  const std::string text = v;
  const auto colon = text.find(':');
  if (text.substr(0, colon) != std::to_string(step)) return;
  std::raise(colon == std::string::npos ? SIGKILL : std::atoi(text.c_str() + colon + 1));
}

}  // namespace flat::train
