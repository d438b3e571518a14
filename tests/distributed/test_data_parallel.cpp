// Data-parallel training as real processes: two ranks of this test binary
// (the hidden "[dp_worker]" case, through the store backend on the CPU) each
// train on half the batch with GradientSync and must end with the parameters
// of one process trained on the whole batch; a SIGKILLed rank makes the
// other one fail with a message naming the dead rank instead of hanging.
#include <cstdio>
#include <filesystem>

#include "flat/core/error.h"
#include "flat/core/tensor_io.h"
#include "flat/distributed/gradient_sync.h"
#include "flat/distributed/overlapped_reducer.h"
#include "flat/distributed/process_group.h"
#include "free_port.h"
#include "test_support.h"
#include "support/process.h"

namespace fs = std::filesystem;
using namespace flat::distributed;

namespace {

constexpr int64_t kSteps = 5;

using flat::test::running;
using flat::test::wait_bounded;

// Trains a small MLP for `steps` SGD steps on rank `rank`'s share of a fixed
// batch of 8; with `group` the gradients are averaged over the ranks. Rank 0
// starts from seed 0 and the others from other seeds (the broadcast must fix
// that). `extra` enters only rank 0's loss: the other ranks have no gradient
// for it, as an unused branch would. The objective of all ranks together is
// the one-process objective: mse(whole batch) + 0.5 * |extra|^2.
// With `overlap` the buckets (of 64 bytes: one per tensor or so) are
// all-reduced from autograd hooks during backward (OverlappedReducer);
// `started` then counts the buckets that started before backward returned.
flat::TensorMap train(ProcessGroup* group, int64_t rank, int64_t world, int64_t steps,
                      const std::function<void()>& after_first_step = nullptr, bool overlap = false,
                      int64_t* started = nullptr) {
  torch::manual_seed(1);
  const at::Tensor x = torch::randn({8, 6}), y = torch::randn({8, 3});
  torch::manual_seed(rank == 0 ? 0 : 100 + rank);
  torch::nn::Sequential model(torch::nn::Linear(6, 16), torch::nn::Tanh(), torch::nn::Linear(16, 3));
  at::Tensor extra = torch::randn({3}).requires_grad_(true);
  // `extra` first: it is the last bucket, so that rank 1's buckets of the
  // model (before it in backward order) need not wait for it.
  std::vector<at::Tensor> params = {extra};
  for (const auto& p : model->parameters()) params.push_back(p);
  std::unique_ptr<GradientSync> sync;
  std::unique_ptr<OverlappedReducer> reducer;
  if (group) {
    broadcast_tensors(*group, params);
    if (overlap) {
      reducer = std::make_unique<OverlappedReducer>(*group, params, GradientSyncOptions{64});
    } else {
      sync = std::make_unique<GradientSync>(*group, params);
    }
  }
  torch::optim::SGD opt(params, torch::optim::SGDOptions(0.1).momentum(0.9));
  const at::Tensor xs = x.chunk(world)[rank], ys = y.chunk(world)[rank];
  for (int64_t step = 0; step < steps; ++step) {
    opt.zero_grad();  // gradients become undefined: rank > 0 has none for `extra`
    if (reducer) reducer->prepare();
    at::Tensor loss = torch::mse_loss(model->forward(xs), ys);
    if (rank == 0) loss = loss + 0.5 * static_cast<double>(world) * extra.pow(2).sum();
    loss.backward();
    if (sync) sync->all_reduce_gradients();
    if (reducer) {
      reducer->finish();
      if (started) *started += reducer->started_in_backward();
    }
    opt.step();
    if (step == 0 && after_first_step) after_first_step();
  }
  flat::TensorMap out;
  for (const auto& kv : model->named_parameters()) out[kv.key()] = kv.value().detach().clone();
  out["extra"] = extra.detach().clone();
  return out;
}

struct Workers {
  std::vector<flat::test::Child> children;
  std::vector<std::string> outputs, ready;
};

// Starts ranks 0 and 1 of this binary's worker case.
Workers start_workers(const fs::path& dir, int64_t steps, int64_t timeout_ms, const std::string& backend = "store",
                      const std::vector<std::string>& extra_env = {}) {
  const std::string self = fs::read_symlink("/proc/self/exe").string();
  const std::string port = std::to_string(flat::test::free_port());
  Workers w;
  for (int rank = 0; rank < 2; ++rank) {
    const std::string r = std::to_string(rank);
    w.outputs.push_back((dir / ("rank" + r + ".safetensors")).string());
    w.ready.push_back((dir / ("rank" + r + ".ready")).string());
    std::vector<std::string> env = {"RANK=" + r, "LOCAL_RANK=" + r, "WORLD_SIZE=2", "MASTER_ADDR=127.0.0.1",
                                    "MASTER_PORT=" + port, "FLAT_DP_OUT=" + w.outputs.back(),
                                    "FLAT_DP_READY=" + w.ready.back(), "FLAT_DP_STEPS=" + std::to_string(steps),
                                    "FLAT_DP_BACKEND=" + backend, "FLAT_DP_TIMEOUT_MS=" + std::to_string(timeout_ms)};
    env.insert(env.end(), extra_env.begin(), extra_env.end());
    w.children.push_back(flat::test::spawn({self, "[dp_worker]"}, (dir / ("rank" + r + ".log")).string(), env));
    REQUIRE(w.children.back().pid > 0);
  }
  return w;
}

}  // namespace

// One rank of the tests below (hidden: it runs only when they start it).
TEST_CASE("data-parallel worker", "[.dp_worker]") {
  const char* out = std::getenv("FLAT_DP_OUT");
  if (!out) FLAT_SKIP("started by the data-parallel tests only");
  try {
    const DistributedEnv env = read_distributed_env();
    const auto timeout = std::chrono::milliseconds(std::stoll(std::getenv("FLAT_DP_TIMEOUT_MS")));
    const char* backend = std::getenv("FLAT_DP_BACKEND");
    auto group = init_process_group(env, backend ? backend : "store", timeout, std::getenv("FLAT_DP_WATCH") != nullptr);
    const std::string ready = std::getenv("FLAT_DP_READY");
    int64_t started = 0;
    const auto params = train(group.get(), env.rank, env.world_size, std::stoll(std::getenv("FLAT_DP_STEPS")),
                              [&] { std::ofstream(ready) << "ok\n"; }, std::getenv("FLAT_DP_OVERLAP") != nullptr,
                              &started);
    std::printf("buckets started during backward: %lld\n", static_cast<long long>(started));
    group->shutdown();
    flat::save_safetensors(out, params);
  } catch (const std::exception& e) {
    // What a launcher would log; _Exit: no destructor may wait on a dead peer.
    std::fprintf(stderr, "worker failed: %s\n", e.what());
    std::fflush(stderr);
    std::_Exit(3);
  }
}

TEST_CASE("data parallel: two ranks on half batches end where one process on the whole batch ends",
          "[distributed]") {
  // c10d's Gloo (PyTorch's CPU engine) where this build has its headers, and the store backend.
  std::string backend = "store";
  bool overlap = false;
  SECTION("store") { backend = "store"; }
  SECTION("gloo") {
    if (!gloo_backend_available()) FLAT_SKIP("this build has no gloo headers (Debian package libgloo-dev)");
    backend = "gloo";
  }
  SECTION("gloo, buckets all-reduced during backward") {
    if (!gloo_backend_available()) FLAT_SKIP("this build has no gloo headers (Debian package libgloo-dev)");
    backend = "gloo";
    overlap = true;
  }
  const std::string name = backend + (overlap ? "_overlap" : "");
  const fs::path dir = flat::test::scratch_dir("dp_equivalence_" + name);
  Workers w = start_workers(dir, kSteps, 60000, backend,
                            overlap ? std::vector<std::string>{"FLAT_DP_OVERLAP=1", "FLAT_DP_WATCH=1"}
                                    : std::vector<std::string>{});
  for (size_t r = 0; r < 2; ++r) {
    const int rc = wait_bounded(w.children[r], 180);
    const std::string log = flat::test::read_file(w.children[r].log);
    INFO("rank " << r << " log:\n" << log);
    REQUIRE(rc == 0);
    // Rank 1 has no gradient for `extra` (the last bucket): it starts at
    // finish(); the model's four buckets start from the hooks on both ranks.
    if (overlap) CHECK_THAT(log, FLAT_CONTAINS("buckets started during backward: " + std::to_string(4 * kSteps + (r == 0 ? kSteps : 0))));
  }
  const flat::TensorMap rank0 = flat::load_safetensors(w.outputs[0]);
  const flat::TensorMap rank1 = flat::load_safetensors(w.outputs[1]);
  const flat::TensorMap one = train(nullptr, 0, 1, kSteps);
  const flat::TensorMap start = train(nullptr, 0, 1, 0);
  REQUIRE(rank0.size() == one.size());
  double worst = 0;
  for (const auto& [name, value] : one) {
    INFO(name);
    REQUIRE(rank0.count(name) == 1);
    REQUIRE(rank1.count(name) == 1);
    // Every rank gets the same sums (store: in rank order; gloo: one reduction result broadcast).
    CHECK(torch::equal(rank0.at(name), rank1.at(name)));
    // fp32 sums in another order than one process's: relative 1e-5.
    const double err = flat::test::rel_error(rank0.at(name), value);
    worst = std::max(worst, err);
    CHECK(err < 1e-5);
    // Training moved every tensor (the comparison is not of two untouched models).
    CHECK(flat::test::rel_error(value, start.at(name)) > 1e-3);
  }
  std::printf("data parallel (%s): worst relative difference to one process over %zu tensors: %.3g\n", name.c_str(),
              one.size(), worst);
}

TEST_CASE("data parallel: a SIGKILLed rank makes the other fail naming it, within the timeout", "[distributed]") {
  // store: the backend names the peer it waits for; gloo: c10d's error, then
  // the heartbeats (peer_watch.h) name the rank that went silent.
  std::string backend = "store";
  int victim = 1;
  auto victims = [&] {
    SECTION("rank 1 (a client of the store) dies") { victim = 1; }
    SECTION("rank 0 (the store's server) dies") { victim = 0; }
  };
  SECTION("store") {
    backend = "store";
    victims();
  }
  SECTION("gloo, with heartbeats") {
    if (!gloo_backend_available()) FLAT_SKIP("this build has no gloo headers (Debian package libgloo-dev)");
    backend = "gloo";
    victims();
  }
  const int survivor = 1 - victim;
  const fs::path dir = flat::test::scratch_dir("dp_kill_" + backend + "_rank" + std::to_string(victim));
  Workers w = start_workers(dir, 1'000'000'000, 10000, backend,  // trains until stopped
                            backend == "gloo" ? std::vector<std::string>{"FLAT_DP_WATCH=1"} : std::vector<std::string>{});
  const bool both_ready = flat::test::wait_until(
      [&] {
        return (fs::exists(w.ready[0]) && fs::exists(w.ready[1])) || !running(w.children[0]) ||
               !running(w.children[1]);
      },
      120);
  INFO("rank 0 log:\n" << flat::test::read_file(w.children[0].log) << "\nrank 1 log:\n"
                       << flat::test::read_file(w.children[1].log));
  if (!both_ready || !running(w.children[0]) || !running(w.children[1])) {
    for (auto& c : w.children) wait_bounded(c, 0);
    FAIL("the workers did not both reach their first step");
  }
  REQUIRE(kill(w.children[victim].pid, SIGKILL) == 0);
  const auto killed = std::chrono::steady_clock::now();
  CHECK(wait_bounded(w.children[victim], 30) == 128 + SIGKILL);
  const int rc = wait_bounded(w.children[survivor], 60);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - killed).count();
  const std::string log = flat::test::read_file(w.children[survivor].log);
  INFO("survivor's log:\n" << log);
  CHECK(rc != 0);
  CHECK(rc != -2);  // it ended by itself
  CHECK(seconds < 60);  // store: rank 1 fails at once, rank 0 after the 10 s timeout; gloo: a few seconds
  CHECK_THAT(log, FLAT_CONTAINS("rank " + std::to_string(survivor)));
  if (backend == "store") {
    CHECK_THAT(log, FLAT_CONTAINS("rank " + std::to_string(victim) + " dead"));
  } else if (victim == 1) {
    CHECK_THAT(log, FLAT_CONTAINS("rank 1 sent no heartbeat"));
  } else {
    CHECK_THAT(log, FLAT_CONTAINS("rank 0, which serves the store, is unreachable"));
  }
  std::printf("data parallel (%s): rank %d noticed the death of rank %d after %.1f s (exit %d)\n", backend.c_str(),
              survivor, victim, seconds, rc);
}
