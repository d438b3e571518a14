#include "flat/distributed/process_group.h"

#include <torch/csrc/distributed/c10d/TCPStore.hpp>

#include "distributed/gloo_process_group.h"
#include "distributed/nccl_process_group.h"
#include "distributed/store_process_group.h"
#include "flat/core/error.h"

namespace flat::distributed {

std::unique_ptr<ProcessGroup> init_process_group(const DistributedEnv& env, const std::string& backend,
                                                 std::chrono::milliseconds timeout) {
  FLAT_CHECK(backend == "gloo" || backend == "store" || backend == "nccl",
             "distributed: unknown backend '" + backend + "' (expected gloo, nccl or store)");
  FLAT_CHECK(env.world_size >= 1 && env.rank >= 0 && env.rank < env.world_size,
             "distributed: rank " + std::to_string(env.rank) + " is outside a world of " +
                 std::to_string(env.world_size));
  FLAT_CHECK(timeout.count() > 0, "distributed: the timeout must be positive");
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
  if (backend == "nccl") return detail::make_nccl_process_group(store, env.rank, env.world_size, timeout);
  if (backend == "gloo") return detail::make_gloo_process_group(store, env.rank, env.world_size, timeout);
  return detail::make_store_process_group(store, env.rank, env.world_size, timeout);
}

bool gloo_backend_available() { return detail::gloo_available(); }

}  // namespace flat::distributed
