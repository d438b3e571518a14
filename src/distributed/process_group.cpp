#include "flat/distributed/process_group.h"

#include <csignal>

#include <torch/csrc/distributed/c10d/TCPStore.hpp>

#include "distributed/gloo_process_group.h"
#include "distributed/nccl_process_group.h"
#include "distributed/peer_watch.h"
#include "distributed/store_process_group.h"
#include "flat/core/error.h"

namespace flat::distributed {

namespace {

// A collective that finished when it was started (backends without async ones).
class DoneWork : public Work {
 public:
  void wait() override {}
};

}  // namespace

ProcessGroup::ProcessGroup(int64_t rank, int64_t world_size) : rank_(rank), world_size_(world_size) {}

ProcessGroup::~ProcessGroup() = default;  // the watch stops with it

std::unique_ptr<Work> ProcessGroup::allreduce_sum_async(at::Tensor& tensor) {
  allreduce_sum(tensor);
  return std::make_unique<DoneWork>();
}

std::string ProcessGroup::diagnose_peers() { return watch_ ? watch_->diagnose() : std::string(); }

void ProcessGroup::shutdown() {
  close_backend();
  if (watch_) watch_->finish();
}

void ProcessGroup::set_peer_watch(std::unique_ptr<detail::PeerWatch> watch) { watch_ = std::move(watch); }

std::vector<double> sum_over_ranks(ProcessGroup& group, const std::vector<double>& values, const at::Device& device) {
  if (values.empty()) return {};
  at::Tensor t = at::tensor(values, at::TensorOptions().dtype(at::kDouble)).to(device);
  group.allreduce_sum(t);
  t = t.cpu();
  const double* p = t.data_ptr<double>();
  return std::vector<double>(p, p + t.numel());
}

std::unique_ptr<ProcessGroup> init_process_group(const DistributedEnv& env, const std::string& backend,
                                                 std::chrono::milliseconds timeout, bool watch_peers) {
  FLAT_CHECK(backend == "gloo" || backend == "store" || backend == "nccl",
             "distributed: unknown backend '" + backend + "' (expected gloo, nccl or store)");
  FLAT_CHECK(env.world_size >= 1 && env.rank >= 0 && env.rank < env.world_size,
             "distributed: rank " + std::to_string(env.rank) + " is outside a world of " +
                 std::to_string(env.world_size));
  FLAT_CHECK(timeout.count() > 0, "distributed: the timeout must be positive");
  // A write to the socket of a peer that died must fail as an error, which
  // names the dead rank (the heartbeats' verdict), not end this rank by
  // SIGPIPE without a word.
  if (env.world_size > 1) std::signal(SIGPIPE, SIG_IGN);
  c10d::TCPStoreOptions opts;
  opts.port = static_cast<std::uint16_t>(env.port);
  opts.isServer = env.rank == 0;
  opts.numWorkers = static_cast<std::size_t>(env.world_size);
  opts.waitWorkers = true;  // the server returns once every rank has connected
  opts.timeout = timeout;
  c10::intrusive_ptr<c10d::Store> store;
  try {
    store = c10::make_intrusive<c10d::TCPStore>(env.master_addr, opts);
  } catch (const c10::Error& e) {
    fail("distributed: rank " + std::to_string(env.rank) + " of " + std::to_string(env.world_size) +
         ": rendezvous at " + env.master_addr + ":" + std::to_string(env.port) + " failed within " +
         std::to_string(timeout.count()) + " ms (" + (env.rank == 0 ? "not every rank arrived" : "rank 0 unreachable") +
         "): " + e.what_without_backtrace());
  }
  std::unique_ptr<ProcessGroup> group;
  if (backend == "nccl") {
    group = detail::make_nccl_process_group(store, env.rank, env.world_size, timeout);
  } else if (backend == "gloo") {
    group = detail::make_gloo_process_group(store, env.rank, env.world_size, timeout);
  } else {
    group = detail::make_store_process_group(store, env.rank, env.world_size, timeout);
  }
  if (watch_peers && env.world_size > 1)
    group->set_peer_watch(std::make_unique<detail::PeerWatch>(store->clone(), env.rank, env.world_size, timeout));
  return group;
}

bool gloo_backend_available() { return detail::gloo_available(); }

}  // namespace flat::distributed
