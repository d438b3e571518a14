// A ProcessGroup over one of c10d's own backends (ProcessGroupGloo,
// ProcessGroupNCCL): the collectives are c10d's; this only waits for them and
// names the ranks when a peer died or hangs (the backend's own timeout, then
// the heartbeats' verdict: ProcessGroup::diagnose_peers).
#pragma once
#include <memory>
#include <string>
#include <utility>

#include <spdlog/spdlog.h>
#include <torch/csrc/distributed/c10d/Backend.hpp>
#include <torch/csrc/distributed/c10d/Store.hpp>

#include "flat/core/error.h"
#include "flat/distributed/process_group.h"

namespace flat::distributed::detail {

class C10dProcessGroup : public ProcessGroup {
 public:
  C10dProcessGroup(c10::intrusive_ptr<c10d::Backend> backend, std::string name, int64_t rank, int64_t world_size)
      : ProcessGroup(rank, world_size), backend_(std::move(backend)), name_(std::move(name)) {}
  // After a failure the backend is left alive: tearing it down may wait on
  // the dead peer, and the process is about to end anyway.
  ~C10dProcessGroup() override {
    if (failed_) (void)backend_.release();
  }
  std::string backend() const override { return name_; }

  void allreduce_sum(at::Tensor& tensor) override { allreduce_sum_async(tensor)->wait(); }
  void broadcast(at::Tensor& tensor, int64_t root) override {
    std::vector<at::Tensor> v{tensor};
    c10d::BroadcastOptions o;
    o.rootRank = root;
    Pending(this, "broadcast", [&] { return backend_->broadcast(v, o); }).wait();
  }
  void close_backend() override {
    try {
      backend_->shutdown();
    } catch (const std::exception& e) {
      failed_ = true;  // leave it alone in the destructor too
      spdlog::warn("distributed ({}): rank {}: shutting the backend down failed: {}", name_, rank(), e.what());
    }
  }
  std::unique_ptr<Work> allreduce_sum_async(at::Tensor& tensor) override {
    std::vector<at::Tensor> v{tensor};
    c10d::AllreduceOptions o;
    o.reduceOp = c10d::ReduceOp::SUM;
    return std::make_unique<Pending>(this, "allreduce", [&] { return backend_->allreduce(v, o); });
  }

 private:
  // A started c10d collective; starting it may already fail (a closed connection).
  class Pending : public Work {
   public:
    template <class F>
    Pending(C10dProcessGroup* group, const char* what, const F& start) : group_(group), what_(what) {
      try {
        work_ = start();
      } catch (const c10::Error& e) {
        group_->failed(what_, e.what_without_backtrace());
      } catch (const std::exception& e) {
        group_->failed(what_, e.what());
      }
    }
    void wait() override {
      try {
        work_->wait();
      } catch (const c10::Error& e) {
        group_->failed(what_, e.what_without_backtrace());
      } catch (const std::exception& e) {
        group_->failed(what_, e.what());
      }
    }

   private:
    C10dProcessGroup* group_;
    const char* what_;
    c10::intrusive_ptr<c10d::Work> work_;
  };

  [[noreturn]] void failed(const char* what, const std::string& error) {
    failed_ = true;
    const std::string peers = diagnose_peers();
    fail("distributed (" + name_ + "): rank " + std::to_string(rank()) + " of " + std::to_string(world_size()) +
         ": " + what + " failed: " + (peers.empty() ? "a peer died, hangs or is unreachable" : peers) + " [" +
         error.substr(0, 300) + "]");
  }

  c10::intrusive_ptr<c10d::Backend> backend_;
  std::string name_;
  bool failed_ = false;
};

// A C10dProcessGroup over a new c10d backend `Backend` (c10d::ProcessGroupGloo,
// c10d::ProcessGroupNCCL) of rank `rank`, which meets its peers through
// `store`; `options`: the backend's own (its timeout among them).
template <class Backend>
std::unique_ptr<ProcessGroup> make_c10d_process_group(const c10::intrusive_ptr<c10d::Store>& store, int64_t rank,
                                                      int64_t world_size,
                                                      c10::intrusive_ptr<typename Backend::Options> options,
                                                      const std::string& name) {
  auto backend =
      c10::make_intrusive<Backend>(store, static_cast<int>(rank), static_cast<int>(world_size), std::move(options));
  return std::make_unique<C10dProcessGroup>(std::move(backend), name, rank, world_size);
}

}  // namespace flat::distributed::detail
