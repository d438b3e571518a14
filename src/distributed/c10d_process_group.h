// A ProcessGroup over one of c10d's own backends (ProcessGroupGloo,
// ProcessGroupNCCL): the collectives are c10d's; this only waits for them and
// names the rank when a peer died or hangs (the backend's own timeout).
#pragma once
#include <string>
#include <utility>

#include <torch/csrc/distributed/c10d/Backend.hpp>

#include "flat/core/error.h"
#include "flat/distributed/process_group.h"

namespace flat::distributed::detail {

class C10dProcessGroup : public ProcessGroup {
 public:
  C10dProcessGroup(c10::intrusive_ptr<c10d::Backend> backend, std::string name, int64_t rank, int64_t world_size)
      : ProcessGroup(rank, world_size), backend_(std::move(backend)), name_(std::move(name)) {}
  std::string backend() const override { return name_; }

  void allreduce_sum(at::Tensor& tensor) override {
    std::vector<at::Tensor> v{tensor};
    c10d::AllreduceOptions o;
    o.reduceOp = c10d::ReduceOp::SUM;
    wait([&] { return backend_->allreduce(v, o); }, "allreduce");
  }
  void broadcast(at::Tensor& tensor, int64_t root) override {
    std::vector<at::Tensor> v{tensor};
    c10d::BroadcastOptions o;
    o.rootRank = root;
    wait([&] { return backend_->broadcast(v, o); }, "broadcast");
  }

 private:
  c10::intrusive_ptr<c10d::Backend> backend_;
  std::string name_;
  template <class F>
  void wait(const F& start, const char* what) {
    try {
      start()->wait();
    } catch (const std::exception& e) {
      fail("distributed (" + name_ + "): rank " + std::to_string(rank()) + " of " + std::to_string(world_size()) +
           ": " + what + " failed (a peer died, hangs or is unreachable): " + e.what());
    }
  }
};

}  // namespace flat::distributed::detail
