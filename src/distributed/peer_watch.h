// Heartbeats through the store (process_group.h): a thread on every rank adds
// one to "flat/heartbeat/<rank>" every period and reads the peers' counters.
// A peer whose counter stands still for `timeout` is dead or stopped (SIGKILL,
// SIGSTOP, its host gone): the watch logs a message naming it and ends this
// process, because the main thread may be blocked where nothing can reach it
// (an NCCL stream synchronisation). A store that cannot be reached means rank
// 0, its server, is gone: the same, at once.
//
// The thread has a store connection of its own (a clone): a collective of the
// store backend blocks its connection while it waits.
#pragma once
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <torch/csrc/distributed/c10d/Store.hpp>

namespace flat::distributed::detail {

class PeerWatch {
 public:
  PeerWatch(c10::intrusive_ptr<c10d::Store> store, int64_t rank, int64_t world_size,
            std::chrono::milliseconds timeout);
  ~PeerWatch();  // stop()
  PeerWatch(const PeerWatch&) = delete;
  PeerWatch& operator=(const PeerWatch&) = delete;

  // Ends the thread (idempotent); from then on nothing is watched.
  void stop();
  // The clean end of the job: stop(), then rank 0 waits (up to the timeout)
  // until every rank has got here, so that it serves the store until no rank
  // needs it any more.
  void finish();
  // Names the peers that went silent, waiting up to four periods for a peer
  // that died a moment ago to show it; "" when every peer is still beating.
  std::string diagnose();

  std::chrono::milliseconds period() const { return period_; }

 private:
  // Shared with the thread, which may outlive this object: stop() detaches a
  // thread stuck in a store call (a SIGSTOPped rank 0) instead of hanging.
  struct State {
    c10::intrusive_ptr<c10d::Store> store;
    int64_t rank = 0, world_size = 1;
    std::chrono::milliseconds timeout{0}, period{0};
    std::mutex mutex;
    std::condition_variable cv;
    bool stop = false, exited = false, store_lost = false;
    std::string store_error;
    std::vector<int64_t> count;  // the peers' counters as last read
    std::vector<std::chrono::steady_clock::time_point> changed;  // when each last moved
  };
  static void run(std::shared_ptr<State> state);
  static std::string silent_peers(const State& s, std::chrono::milliseconds at_least);  // caller holds the mutex

  std::shared_ptr<State> state_;
  std::chrono::milliseconds period_;
  std::thread thread_;
};

}  // namespace flat::distributed::detail
