#include "distributed/gloo_process_group.h"

#include "flat/core/error.h"

#if __has_include(<gloo/config.h>)
#define FLAT_HAVE_GLOO 1
#ifndef USE_C10D_GLOO
#define USE_C10D_GLOO 1  // the wheel's libtorch_cpu is built with it; its header is guarded by it
#endif
#include <torch/csrc/distributed/c10d/ProcessGroupGloo.hpp>
#else
#define FLAT_HAVE_GLOO 0
#endif

namespace flat::distributed::detail {

bool gloo_available() { return FLAT_HAVE_GLOO != 0; }

#if FLAT_HAVE_GLOO
namespace {

class GlooProcessGroup : public ProcessGroup {
 public:
  GlooProcessGroup(c10::intrusive_ptr<c10d::ProcessGroupGloo> pg, int64_t rank, int64_t world_size)
      : ProcessGroup(rank, world_size), pg_(std::move(pg)) {}
  std::string backend() const override { return "gloo"; }

  void allreduce_sum(at::Tensor& tensor) override {
    std::vector<at::Tensor> v{tensor};
    c10d::AllreduceOptions o;
    o.reduceOp = c10d::ReduceOp::SUM;
    wait(pg_->allreduce(v, o), "allreduce");
  }
  void broadcast(at::Tensor& tensor, int64_t root) override {
    std::vector<at::Tensor> v{tensor};
    c10d::BroadcastOptions o;
    o.rootRank = root;
    wait(pg_->broadcast(v, o), "broadcast");
  }

 private:
  c10::intrusive_ptr<c10d::ProcessGroupGloo> pg_;
  // A peer that died or hangs makes the collective fail after the timeout:
  // say which rank saw it, not only what gloo says.
  void wait(const c10::intrusive_ptr<c10d::Work>& work, const char* what) {
    try {
      work->wait();
    } catch (const std::exception& e) {
      fail("distributed (gloo): rank " + std::to_string(rank()) + " of " + std::to_string(world_size()) + ": " +
           what + " failed (a peer died, hangs or is unreachable): " + e.what());
    }
  }
};

}  // namespace

std::unique_ptr<ProcessGroup> make_gloo_process_group(c10::intrusive_ptr<c10d::Store> store, int64_t rank,
                                                      int64_t world_size, std::chrono::milliseconds timeout) {
  auto opts = c10d::ProcessGroupGloo::Options::create();
  opts->timeout = timeout;
  opts->devices.push_back(c10d::ProcessGroupGloo::createDefaultDevice());
  auto pg = c10::make_intrusive<c10d::ProcessGroupGloo>(store, static_cast<int>(rank), static_cast<int>(world_size),
                                                        opts);
  return std::make_unique<GlooProcessGroup>(std::move(pg), rank, world_size);
}
#else
std::unique_ptr<ProcessGroup> make_gloo_process_group(c10::intrusive_ptr<c10d::Store>, int64_t, int64_t,
                                                      std::chrono::milliseconds) {
  fail("distributed: backend gloo needs the gloo headers (Debian package libgloo-dev), which this build did not "
       "find; use store");
}
#endif

}  // namespace flat::distributed::detail
