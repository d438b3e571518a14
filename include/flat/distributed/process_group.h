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
#pragma once
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>

#include <ATen/ATen.h>

#include "flat/distributed/distributed_env.h"

namespace flat::distributed {

class ProcessGroup {
 public:
  ProcessGroup(int64_t rank, int64_t world_size) : rank_(rank), world_size_(world_size) {}
  virtual ~ProcessGroup() = default;
  ProcessGroup(const ProcessGroup&) = delete;
  ProcessGroup& operator=(const ProcessGroup&) = delete;

  int64_t rank() const { return rank_; }
  int64_t world_size() const { return world_size_; }
  virtual std::string backend() const = 0;

  // In place: `tensor` becomes the sum of every rank's `tensor`.
  virtual void allreduce_sum(at::Tensor& tensor) = 0;
  // In place: `tensor` becomes rank `root`'s `tensor`.
  virtual void broadcast(at::Tensor& tensor, int64_t root) = 0;

 private:
  int64_t rank_, world_size_;
};

// Rendezvous at env.master_addr:env.port and the group of env.world_size
// ranks; `backend` is "gloo", "nccl" or "store". Waits up to `timeout` for all ranks
// to arrive, and the collectives use the same timeout.
std::unique_ptr<ProcessGroup> init_process_group(const DistributedEnv& env, const std::string& backend,
                                                 std::chrono::milliseconds timeout);

// True when this build can construct the "gloo" backend.
bool gloo_backend_available();

}  // namespace flat::distributed
