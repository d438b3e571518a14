#include "distributed/nccl_process_group.h"

#include "flat/core/error.h"

// c10d's NCCL header includes <nccl.h>: CUDA toolkits without NCCL get the
// runtime error below instead of a failed build.
#if FLAT_WITH_CUDA && __has_include(<nccl.h>)
#define FLAT_HAVE_NCCL 1
#include <torch/csrc/distributed/c10d/ProcessGroupNCCL.hpp>

#include "distributed/c10d_process_group.h"
#else
#define FLAT_HAVE_NCCL 0
#endif

namespace flat::distributed::detail {

#if FLAT_HAVE_NCCL
// Each collective is enqueued on NCCL's stream and waited for; the caller has
// made this rank's GPU the current device (local_rank).
std::unique_ptr<ProcessGroup> make_nccl_process_group(c10::intrusive_ptr<c10d::Store> store, int64_t rank,
                                                      int64_t world_size, std::chrono::milliseconds timeout) {
  auto opts = c10d::ProcessGroupNCCL::Options::create();
  opts->timeout = timeout;  // NCCL's watchdog aborts a collective that outlives it
  return make_c10d_process_group<c10d::ProcessGroupNCCL>(store, rank, world_size, opts, "nccl");
}
#else
std::unique_ptr<ProcessGroup> make_nccl_process_group(c10::intrusive_ptr<c10d::Store>, int64_t, int64_t,
                                                      std::chrono::milliseconds) {
  fail(std::string("distributed: backend nccl needs a CUDA build with nccl.h (") +
       (FLAT_WITH_CUDA ? "nccl.h was not found" : "FLAT_WITH_CUDA=OFF") + " here); use store on the CPU");
}
#endif

}  // namespace flat::distributed::detail
