// init_process_group in one process: a world of one works without peers, a
// rendezvous that never completes ends with an error instead of hanging, and
// backends are checked by name.
#include <chrono>

#include "flat/core/error.h"
#include "flat/distributed/process_group.h"
#include "free_port.h"
#include "support/error_of.h"
#include "test_support.h"

using namespace flat::distributed;
using namespace std::chrono_literals;

namespace {

DistributedEnv local_env(int64_t rank, int64_t world_size) {
  DistributedEnv env;
  env.rank = rank;
  env.world_size = world_size;
  env.port = flat::test::free_port();
  return env;
}

using flat::test::error_of;

}  // namespace

TEST_CASE("process group: a world of one reduces and broadcasts to itself", "[distributed]") {
  auto group = init_process_group(local_env(0, 1), "store", 10s);
  CHECK(group->backend() == "store");
  CHECK(group->world_size() == 1);
  at::Tensor t = torch::tensor({1.5f, -2.f});
  group->allreduce_sum(t);
  CHECK(torch::equal(t, torch::tensor({1.5f, -2.f})));
  group->broadcast(t, 0);
  CHECK(torch::equal(t, torch::tensor({1.5f, -2.f})));
  CHECK_THAT(error_of([&] { group->broadcast(t, 1); }), FLAT_CONTAINS("broadcast from rank 1 outside a world of 1"));
}

TEST_CASE("process group: gloo, a world of one", "[distributed]") {
  if (!gloo_backend_available()) FLAT_SKIP("this build has no gloo headers (Debian package libgloo-dev)");
  auto group = init_process_group(local_env(0, 1), "gloo", 10s);
  CHECK(group->backend() == "gloo");
  at::Tensor t = torch::tensor({1.5f, -2.f});
  group->allreduce_sum(t);
  CHECK(torch::equal(t, torch::tensor({1.5f, -2.f})));
}

TEST_CASE("process group: a rank that never arrives ends the rendezvous with an error", "[distributed]") {
  const auto start = std::chrono::steady_clock::now();
  const std::string message = error_of([] { init_process_group(local_env(0, 2), "store", 1s); });
  CHECK_THAT(message, FLAT_CONTAINS("rank 0 of 2"));
  CHECK_THAT(message, FLAT_CONTAINS("not every rank arrived"));
  CHECK(std::chrono::steady_clock::now() - start < 30s);
}

TEST_CASE("process group: backends are checked by name", "[distributed]") {
  CHECK_THAT(error_of([] { init_process_group(local_env(0, 1), "mpi", 1s); }), FLAT_CONTAINS("unknown backend 'mpi'"));
  if (!gloo_backend_available())
    CHECK_THAT(error_of([] { init_process_group(local_env(0, 1), "gloo", 1s); }), FLAT_CONTAINS("libgloo-dev"));
#if !FLAT_WITH_CUDA
  CHECK_THAT(error_of([] { init_process_group(local_env(0, 1), "nccl", 1s); }), FLAT_CONTAINS("FLAT_WITH_CUDA=OFF"));
#endif
}
