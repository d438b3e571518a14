// The collectives data-parallel training needs, over c10d: one process per
// device, rank 0 serves a c10d::TCPStore at MASTER_ADDR:MASTER_PORT and every
// rank rendezvous there.
//
// Backends:
//   "nccl"  - c10d::ProcessGroupNCCL (CUDA builds; tensors on this rank's GPU).
//   "gloo"  - c10d::ProcessGroupGloo (CPU). The torch wheel ships its code but
//             not the gloo headers its header includes; Debian's libgloo-dev
//             provides them (gloo_backend_available() says whether this build
//             found them).
//   "store" - the collectives through the TCPStore itself (CPU), a fallback
//             for builds without the gloo headers. It moves every tensor
//             through rank 0's store: fine for tests and small models only.
//
// Every rank must call the same collectives in the same order with tensors of
// the same shape and dtype. A dead or stuck peer makes a collective throw
// flat::Error naming this rank and the peer after `timeout`, never hang.
//
// Peers are also watched through the store (peer_watch.h): every rank bumps a
// heartbeat counter about once a second, and a peer whose counter stands
// still for `timeout` (dead, SIGSTOPped, a host gone) ends this process with
// a message naming it, even where a collective cannot be interrupted (NCCL
// blocks the host in a stream synchronisation, not in wait()).
#pragma once
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <ATen/ATen.h>

#include "flat/distributed/distributed_env.h"

namespace flat::distributed {

namespace detail {
class PeerWatch;
}

// A collective under way (allreduce_sum_async): wait() returns once the
// result is in the tensor (on CUDA: once the current stream is ordered after
// it) and throws flat::Error naming the ranks when a peer failed.
class Work {
 public:
  virtual ~Work() = default;
  virtual void wait() = 0;
};

class ProcessGroup {
 public:
  ProcessGroup(int64_t rank, int64_t world_size);
  virtual ~ProcessGroup();
  ProcessGroup(const ProcessGroup&) = delete;
  ProcessGroup& operator=(const ProcessGroup&) = delete;

  int64_t rank() const { return rank_; }
  int64_t world_size() const { return world_size_; }
  virtual std::string backend() const = 0;

  // In place: `tensor` becomes the sum of every rank's `tensor`.
  virtual void allreduce_sum(at::Tensor& tensor) = 0;
  // In place: `tensor` becomes rank `root`'s `tensor`.
  virtual void broadcast(at::Tensor& tensor, int64_t root) = 0;
  // Starts allreduce_sum; `tensor` must stay alive and untouched until wait().
  // Backends without asynchronous collectives finish it here.
  virtual std::unique_ptr<Work> allreduce_sum_async(at::Tensor& tensor);

  // What the heartbeats say about the peers, for an error message: "rank 2
  // sent no heartbeat for 3.1 s (dead or stuck)", "rank 0, which serves the
  // store, is unreachable", or "" without a watch. Takes up to a few
  // heartbeat periods (a peer that died a moment ago still looks alive).
  std::string diagnose_peers();
  // The clean end of a job, on every rank: stops the heartbeats, then waits
  // for every rank, so that rank 0 (the store's server) outlives the others'
  // last use of the store. Not called after an error.
  void shutdown();

  // Used by init_process_group.
  void set_peer_watch(std::unique_ptr<detail::PeerWatch> watch);

 protected:
  // The backend's own clean end, first thing in shutdown() (NCCL frees its
  // communicators; without it c10d warns at exit that none was destroyed).
  virtual void close_backend() {}

 private:
  int64_t rank_, world_size_;
  std::unique_ptr<detail::PeerWatch> watch_;
};

// Rendezvous at env.master_addr:env.port and the group of env.world_size
// ranks; `backend` is "gloo", "nccl" or "store". Waits up to `timeout` for all ranks
// to arrive, and the collectives use the same timeout. With watch_peers (and
// more than one rank) the heartbeats above start.
std::unique_ptr<ProcessGroup> init_process_group(const DistributedEnv& env, const std::string& backend,
                                                 std::chrono::milliseconds timeout, bool watch_peers = false);

// Sums `values` over the ranks (one allreduce of float64 on `device`: the
// rank's GPU for nccl, the CPU otherwise). For a step's loss terms and flags.
std::vector<double> sum_over_ranks(ProcessGroup& group, const std::vector<double>& values, const at::Device& device);

// True when this build can construct the "gloo" backend.
bool gloo_backend_available();

}  // namespace flat::distributed
