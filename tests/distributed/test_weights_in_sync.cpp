// check_weights_in_sync against a scripted rank 0: equal tensors pass, one
// changed weight names the tensor and the rank.
#include "flat/distributed/weights_in_sync.h"
#include "test_support.h"

using namespace flat::distributed;

namespace {

// This process is rank 1 of 3; rank 0's fingerprint comes from `rank0`, and
// rank 2 says it differs when `rank2_differs` (rank 0 never differs from itself).
class ScriptedRank1 : public ProcessGroup {
 public:
  ScriptedRank1(at::Tensor rank0, bool rank2_differs)
      : ProcessGroup(1, 3), rank0_(std::move(rank0)), rank2_differs_(rank2_differs) {}
  std::string backend() const override { return "scripted"; }
  void allreduce_sum(at::Tensor& t) override {
    if (rank2_differs_) t[2] += 1;
  }
  void broadcast(at::Tensor& t, int64_t root) override {
    REQUIRE(root == 0);
    t.copy_(rank0_);
  }

 private:
  at::Tensor rank0_;
  bool rank2_differs_;
};

at::Tensor fingerprint(const std::vector<at::Tensor>& ts) {
  std::vector<at::Tensor> parts;
  for (const auto& t : ts) {
    parts.push_back(t.to(at::kDouble).sum().reshape({1}));
    parts.push_back(t.to(at::kDouble).square().sum().reshape({1}));
  }
  return at::cat(parts);
}

}  // namespace

TEST_CASE("weights in sync: the same weights pass; one weight changed by one ulp names the tensor and the rank",
          "[distributed]") {
  torch::manual_seed(0);
  auto a = torch::randn({64, 3}), b = torch::randn({10});
  ScriptedRank1 same(fingerprint({a, b}), false);
  const auto ok = check_weights_in_sync(same, {{"conv.weight", a}, {"conv.bias", b}});
  CHECK(ok.in_sync());

  auto b2 = b.clone();
  b2[3] = std::nextafter(b2[3].item<float>(), 1e9f);  // one float ulp: a drift, not a bug in the check
  ScriptedRank1 other(fingerprint({a, b}), false);
  const auto bad = check_weights_in_sync(other, {{"conv.weight", a}, {"conv.bias", b2}});
  REQUIRE_FALSE(bad.in_sync());
  CHECK(bad.differing_ranks == std::vector<int64_t>{1});
  CHECK(bad.first_tensor == "conv.bias");
  CHECK(bad.here_sum != bad.rank0_sum);
}

TEST_CASE("weights in sync: every rank learns which other rank differs", "[distributed]") {
  auto a = torch::arange(12, torch::kFloat);
  ScriptedRank1 group(fingerprint({a}), true);
  const auto s = check_weights_in_sync(group, {{"w", a}});
  CHECK(s.differing_ranks == std::vector<int64_t>{2});
  CHECK(s.first_tensor.empty());  // this rank holds rank 0's weights
}
