#include "distributed/nccl_process_group.h"

#include "flat/core/error.h"

// c10d's NCCL header includes <nccl.h>: CUDA toolkits without NCCL get the
// runtime error below instead of a failed build.
#if FLAT_WITH_CUDA && __has_include(<nccl.h>)
#define FLAT_HAVE_NCCL 1
#include <torch/csrc/distributed/c10d/ProcessGroupNCCL.hpp>
#else
#define FLAT_HAVE_NCCL 0
#endif

namespace flat::distributed::detail {

#if FLAT_HAVE_NCCL
namespace {

// Each collective is enqueued on NCCL's stream and waited for; the caller has
// made this rank's GPU the current device (local_rank).
class NcclProcessGroup : public ProcessGroup {
 public:
  NcclProcessGroup(c10::intrusive_ptr<c10d::ProcessGroupNCCL> pg, int64_t rank, int64_t world_size)
      : ProcessGroup(rank, world_size), pg_(std::move(pg)) {}
  std::string backend() const override { return "nccl"; }

  void allreduce_sum(at::Tensor& tensor) override {
    std::vector<at::Tensor> v{tensor};
    c10d::AllreduceOptions o;
    o.reduceOp = c10d::ReduceOp::SUM;
    pg_->allreduce(v, o)->wait();
  }
  void broadcast(at::Tensor& tensor, int64_t root) override {
    std::vector<at::Tensor> v{tensor};
    c10d::BroadcastOptions o;
    o.rootRank = root;
    pg_->broadcast(v, o)->wait();
  }

 private:
  c10::intrusive_ptr<c10d::ProcessGroupNCCL> pg_;
};

}  // namespace

std::unique_ptr<ProcessGroup> make_nccl_process_group(c10::intrusive_ptr<c10d::Store> store, int64_t rank,
                                                      int64_t world_size, std::chrono::milliseconds timeout) {
  auto opts = c10d::ProcessGroupNCCL::Options::create();
  opts->timeout = timeout;  // NCCL's watchdog aborts a collective that outlives it
  auto pg = c10::make_intrusive<c10d::ProcessGroupNCCL>(store, static_cast<int>(rank), static_cast<int>(world_size),
                                                        opts);
  return std::make_unique<NcclProcessGroup>(std::move(pg), rank, world_size);
}
#else
std::unique_ptr<ProcessGroup> make_nccl_process_group(c10::intrusive_ptr<c10d::Store>, int64_t, int64_t,
                                                      std::chrono::milliseconds) {
  fail(std::string("distributed: backend nccl needs a CUDA build with nccl.h (") +
       (FLAT_WITH_CUDA ? "nccl.h was not found" : "FLAT_WITH_CUDA=OFF") + " here); use store on the CPU");
}
#endif

}  // namespace flat::distributed::detail
