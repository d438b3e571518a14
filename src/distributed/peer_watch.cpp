#include "distributed/peer_watch.h"

#include <cstdio>
#include <cstdlib>

#include <c10/util/Exception.h>
#include <spdlog/spdlog.h>

namespace flat::distributed::detail {
namespace {

using Clock = std::chrono::steady_clock;

std::string key(int64_t rank) { return "flat/heartbeat/" + std::to_string(rank); }

std::string seconds(Clock::duration d) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.1f s", std::chrono::duration<double>(d).count());
  return text;
}

// The message of a c10::Error without its backtrace, one line.
std::string first_line(const std::exception& e) {
  const auto* c10_error = dynamic_cast<const c10::Error*>(&e);
  std::string text = c10_error ? c10_error->what_without_backtrace() : e.what();
  return text.substr(0, std::min(text.find('\n'), size_t(300)));
}

// Logged from the watch thread, then the process ends: the main thread may be
// blocked where no exception reaches it, and destructors could wait on the
// dead peer. Exit code 1, a runtime error, as any other failure of a rank.
[[noreturn]] void end_process(const std::string& message) {
  spdlog::error("{}", message);
  spdlog::default_logger()->flush();
  std::fflush(stdout);
  std::fflush(stderr);
  std::_Exit(1);
}

}  // namespace

PeerWatch::PeerWatch(c10::intrusive_ptr<c10d::Store> store, int64_t rank, int64_t world_size,
                     std::chrono::milliseconds timeout)
    : state_(std::make_shared<State>()) {
  // About ten beats per timeout, at most one a second: a few store calls a second in all.
  period_ = std::chrono::milliseconds(std::max<int64_t>(50, std::min<int64_t>(1000, timeout.count() / 10)));
  State& s = *state_;
  s.store = std::move(store);
  s.rank = rank;
  s.world_size = world_size;
  s.timeout = timeout;
  s.period = period_;
  s.count.assign(size_t(world_size), -1);
  s.changed.assign(size_t(world_size), Clock::now());
  thread_ = std::thread(run, state_);
}

PeerWatch::~PeerWatch() { stop(); }

void PeerWatch::stop() {
  if (!thread_.joinable()) return;
  std::unique_lock<std::mutex> lock(state_->mutex);
  state_->stop = true;
  state_->cv.notify_all();
  // A store call returns within a period or two; one stuck on a stopped rank 0 does not.
  const bool exited = state_->cv.wait_for(lock, 4 * period_ + std::chrono::seconds(1), [&] { return state_->exited; });
  lock.unlock();
  if (exited) {
    thread_.join();
  } else {
    thread_.detach();  // it holds state_ and ends when its store call does
  }
}

void PeerWatch::finish() {
  stop();
  State& s = *state_;
  try {
    if (s.store->add("flat/finished", 1) == s.world_size) s.store->set("flat/all_finished", std::vector<uint8_t>{1});
    if (s.rank == 0) s.store->wait({"flat/all_finished"}, s.timeout);
  } catch (const std::exception& e) {
    spdlog::warn("distributed: rank {}: not every rank reached the end of the job: {}", s.rank, first_line(e));
  }
}

void PeerWatch::run(std::shared_ptr<State> state) {
  State& s = *state;
  for (;;) {
    std::string lost;
    try {
      s.store->add(key(s.rank), 1);
      std::vector<int64_t> counts(size_t(s.world_size), -1);
      for (int64_t q = 0; q < s.world_size; ++q)
        if (q != s.rank) counts[size_t(q)] = s.store->add(key(q), 0);  // reads without blocking
      std::lock_guard<std::mutex> lock(s.mutex);
      const auto now = Clock::now();
      for (int64_t q = 0; q < s.world_size; ++q) {
        if (q == s.rank || counts[size_t(q)] == s.count[size_t(q)]) continue;
        s.count[size_t(q)] = counts[size_t(q)];
        s.changed[size_t(q)] = now;
      }
      if (!s.stop) lost = silent_peers(s, s.timeout);
    } catch (const std::exception& e) {
      std::lock_guard<std::mutex> lock(s.mutex);
      s.store_lost = true;
      s.store_error = first_line(e);
      if (!s.stop) lost = "rank 0, which serves the store, is unreachable (dead, or its host is gone): " + s.store_error;
    }
    if (!lost.empty())
      end_process("distributed: rank " + std::to_string(s.rank) + " of " + std::to_string(s.world_size) + ": " +
                  lost + "; ending this rank");
    std::unique_lock<std::mutex> lock(s.mutex);
    if (s.store_lost || s.cv.wait_for(lock, s.period, [&] { return s.stop; })) {
      s.exited = true;
      s.cv.notify_all();
      return;
    }
  }
}

std::string PeerWatch::silent_peers(const State& s, std::chrono::milliseconds at_least) {
  std::string out;
  const auto now = Clock::now();
  for (int64_t q = 0; q < s.world_size; ++q) {
    if (q == s.rank || now - s.changed[size_t(q)] < at_least) continue;
    out += (out.empty() ? "" : ", ") + std::string("rank ") + std::to_string(q) + " sent no heartbeat for " +
           seconds(now - s.changed[size_t(q)]);
  }
  if (!out.empty()) out += " (dead or stuck)";
  return out;
}

std::string PeerWatch::diagnose() {
  // A peer is seen to move at most a period after its last beat: four periods show a
  // silence of more than two.
  const auto end = Clock::now() + 4 * period_;
  for (;;) {
    {
      std::lock_guard<std::mutex> lock(state_->mutex);
      if (state_->store_lost) return "rank 0, which serves the store, is unreachable (dead, or its host is gone)";
      const std::string silent = silent_peers(*state_, 2 * period_ + std::chrono::milliseconds(100));
      if (!silent.empty() || Clock::now() > end) return silent;
    }
    std::this_thread::sleep_for(period_ / 4);
  }
}

}  // namespace flat::distributed::detail
