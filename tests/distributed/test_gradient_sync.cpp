// GradientSync's bucketing and its handling of missing gradients, and
// OverlappedReducer's hooks, in one process against a scripted group that
// plays the other rank.
#include <functional>

#include "flat/distributed/gradient_sync.h"
#include "flat/distributed/overlapped_reducer.h"
#include "test_support.h"

using namespace flat::distributed;

namespace {

// World of two: allreduce adds what `peer` says the other rank sent.
class ScriptedGroup : public ProcessGroup {
 public:
  explicit ScriptedGroup(std::function<at::Tensor(const at::Tensor&)> peer)
      : ProcessGroup(0, 2), peer_(std::move(peer)) {}
  std::string backend() const override { return "scripted"; }
  void allreduce_sum(at::Tensor& t) override {
    sizes.push_back(t.numel());
    dtypes.push_back(t.scalar_type());
    t.add_(peer_(t));
  }
  void broadcast(at::Tensor& t, int64_t) override { t.fill_(7); }
  std::vector<int64_t> sizes;
  std::vector<at::ScalarType> dtypes;

 private:
  std::function<at::Tensor(const at::Tensor&)> peer_;
};

at::Tensor param(int64_t n, at::ScalarType dtype = at::kFloat) {
  return torch::zeros({n}, torch::TensorOptions().dtype(dtype)).requires_grad_(true);
}

}  // namespace

TEST_CASE("gradient sync: buckets hold one dtype and device, stay under the size, in reverse order", "[distributed]") {
  ScriptedGroup group([](const at::Tensor& t) { return t.clone(); });
  // floats 1000, 1000, doubles 10, floats 3000 (larger than a bucket: alone), floats 1.
  std::vector<at::Tensor> params = {param(1000), param(1000), param(10, at::kDouble), param(3000), param(1)};
  for (auto& p : params) p.mutable_grad() = torch::ones_like(p);
  GradientSync sync(group, params, GradientSyncOptions{8000});  // 2000 floats
  const auto& b = sync.buckets();
  REQUIRE(b.size() == 4);
  CHECK(b[0].params == std::vector<int64_t>{4});
  CHECK(b[1].params == std::vector<int64_t>{3});
  CHECK(b[2].params == std::vector<int64_t>{2});
  CHECK(b[3].params == std::vector<int64_t>{1, 0});  // exactly 8000 bytes fits
  CHECK(b[3].numel == 2000);
  sync.all_reduce_gradients();
  // One collective per bucket: its gradients plus one presence count per parameter.
  CHECK(group.sizes == std::vector<int64_t>{2, 3001, 11, 2002});
  CHECK(group.dtypes == std::vector<at::ScalarType>{at::kFloat, at::kFloat, at::kDouble, at::kFloat});
  // Both ranks sent ones: the mean is one.
  for (auto& p : params) CHECK(torch::equal(p.grad(), torch::ones_like(p)));
}

TEST_CASE("gradient sync: a gradient missing on some ranks is averaged with zeros, on all ranks none stays none",
          "[distributed]") {
  at::Tensor a = param(3), b = param(2), c = param(2);
  a.mutable_grad() = torch::tensor({1.f, 2.f, 3.f});
  // The other rank: a gradient of ones for a and b, none for c. Layout of the
  // one bucket (reverse order, slots on 16 bytes): c at 0, b at 4, a at 8,
  // then the counts of c, b, a.
  ScriptedGroup group([](const at::Tensor&) {
    return torch::tensor({0.f, 0.f, 0.f, 0.f, 1.f, 1.f, 0.f, 0.f, 1.f, 1.f, 1.f, 0.f, 1.f, 1.f});
  });
  GradientSync sync(group, {a, b, c});
  REQUIRE(sync.buckets().size() == 1);
  sync.all_reduce_gradients();
  CHECK(torch::allclose(a.grad(), torch::tensor({1.f, 1.5f, 2.f})));
  REQUIRE(b.grad().defined());
  CHECK(torch::allclose(b.grad(), torch::full({2}, 0.5f)));
  CHECK_FALSE(c.grad().defined());
}

TEST_CASE("gradient sync: bf16 on the wire sends bf16 buckets and writes fp32 means near the exact ones",
          "[distributed]") {
  ScriptedGroup group([](const at::Tensor& t) { return t * 3; });  // the other rank sent 3x ours
  at::Tensor a = param(1000), b = param(5);
  a.mutable_grad() = torch::linspace(-1, 1, 1000);
  b.mutable_grad() = torch::full({5}, 1.f / 3.f);
  GradientSyncOptions options;
  options.bf16_wire = true;
  GradientSync sync(group, {a, b}, options);
  sync.all_reduce_gradients();
  CHECK(group.dtypes == std::vector<at::ScalarType>{at::kBFloat16});
  CHECK(a.grad().scalar_type() == at::kFloat);
  // Mean of g and 3g: 2g, to bf16's ~3 significant digits, not exactly.
  const auto exact = torch::linspace(-1, 1, 1000) * 2;
  CHECK(flat::test::rel_error(a.grad(), exact) < 1e-2);
  CHECK_FALSE(torch::equal(a.grad(), exact));
  CHECK(torch::allclose(b.grad(), torch::full({5}, 2.f / 3.f), 1e-2));

  // A parameter this rank left without a gradient gets the other rank's mean
  // in its own dtype (an fp32 .grad, never the bf16 of the wire).
  at::Tensor c = param(4);
  ScriptedGroup other([](const at::Tensor&) {  // the peer: gradient 2 for c, and its presence count
    return torch::tensor({2.f, 2.f, 2.f, 2.f, 1.f}).to(at::kBFloat16);
  });
  GradientSync sync_c(other, {c}, options);
  sync_c.all_reduce_gradients();
  REQUIRE(c.grad().defined());
  CHECK(c.grad().scalar_type() == at::kFloat);
  CHECK(torch::equal(c.grad(), torch::ones({4})));
}

TEST_CASE("gradient sync: a caller's own .grad of another layout than its channels-last parameter gets the mean",
          "[distributed]") {
  ScriptedGroup group([](const at::Tensor& t) { return t * 3; });  // the mean is 2x ours
  at::Tensor w = torch::zeros({2, 3, 2, 2, 2}).contiguous(at::MemoryFormat::ChannelsLast3d).requires_grad_(true);
  const at::Tensor g = torch::arange(48, torch::kFloat).view({2, 3, 2, 2, 2});  // contiguous, not w's layout
  w.mutable_grad() = g.clone();
  GradientSync sync(group, {w});
  sync.all_reduce_gradients();
  CHECK(torch::equal(w.grad(), g * 2));
}

TEST_CASE("gradient sync: slots start on 16 bytes; a parameter listed twice is refused", "[distributed]") {
  ScriptedGroup group([](const at::Tensor& t) { return t.clone(); });
  // Reverse order: 3 floats at 0, then 5 floats at 4 (not 3), then 1 double at 0 of its own bucket.
  std::vector<at::Tensor> params = {param(1, at::kDouble), param(5), param(3)};
  GradientSync sync(group, params);
  REQUIRE(sync.buckets().size() == 2);
  CHECK(sync.buckets()[0].offsets == std::vector<int64_t>{0, 4});
  CHECK(sync.buckets()[0].numel == 9);
  params[2].mutable_grad() = torch::full({3}, 2.f);
  params[1].mutable_grad() = torch::full({5}, 3.f);
  params[0].mutable_grad() = torch::full({1}, 4.0, torch::kDouble);
  sync.all_reduce_gradients();
  CHECK(torch::equal(params[2].grad(), torch::full({3}, 2.f)));
  CHECK(torch::equal(params[1].grad(), torch::full({5}, 3.f)));
  CHECK(torch::equal(params[0].grad(), torch::full({1}, 4.0, torch::kDouble)));

  at::Tensor tied = param(4);
  CHECK_THROWS_WITH(GradientSync(group, {tied, param(2), tied}), FLAT_CONTAINS("parameters 0 and 2 are the same tensor"));
}

TEST_CASE("overlapped reducer: a rank that skipped backward gets the others' mean, bf16 wire included",
          "[distributed]") {
  // The peer had gradient 4 for a and none for b (its counts: 1 for a, 0 for b).
  // Bucket layout (reverse order): b (2 values, padded to 4), a (3), then the counts of b, a.
  for (const bool bf16 : {false, true}) {
    CAPTURE(bf16);
    at::Tensor a = param(3), b = param(2);
    ScriptedGroup group([&](const at::Tensor& t) {
      auto peer = torch::tensor({0.f, 0.f, 0.f, 0.f, 4.f, 4.f, 4.f, 0.f, 1.f});
      return peer.to(t.scalar_type());
    });
    GradientSyncOptions options;
    options.bf16_wire = bf16;
    OverlappedReducer reducer(group, {a, b}, options, /*overlap=*/false);
    reducer.prepare();
    // No backward here (a non-finite loss on this rank).
    reducer.finish();
    CHECK(group.dtypes == std::vector<at::ScalarType>{bf16 ? at::kBFloat16 : at::kFloat});
    REQUIRE(a.grad().defined());
    CHECK(a.grad().scalar_type() == at::kFloat);
    CHECK(torch::equal(a.grad(), torch::full({3}, 2.f)));
    CHECK_FALSE(b.grad().defined());
  }
}

TEST_CASE("overlapped reducer: with a bf16 wire the bound gradients get the means, near the exact ones",
          "[distributed]") {
  ScriptedGroup group([](const at::Tensor& t) { return t * 3; });  // the mean is 2x ours
  torch::manual_seed(2);
  torch::nn::Linear lin(6, 5);
  const at::Tensor x = torch::randn({4, 6});
  auto loss_of = [&] { return lin->forward(x).pow(2).sum(); };
  const auto expected = torch::autograd::grad({loss_of()}, {lin->weight, lin->bias});
  GradientSyncOptions options;
  options.bf16_wire = true;
  OverlappedReducer reducer(group, lin->parameters(), options);
  for (auto& p : lin->parameters()) p.mutable_grad() = at::Tensor();
  reducer.prepare();
  loss_of().backward();
  reducer.finish();
  CHECK(group.dtypes == std::vector<at::ScalarType>{at::kBFloat16});
  CHECK(lin->weight.grad().storage().is_alias_of(lin->bias.grad().storage()));  // still the bucket
  CHECK(lin->weight.grad().scalar_type() == at::kFloat);
  CHECK(flat::test::rel_error(lin->weight.grad(), expected[0] * 2) < 1e-2);
  CHECK(flat::test::rel_error(lin->bias.grad(), expected[1] * 2) < 1e-2);
}

TEST_CASE("gradient sync: broadcast_tensors writes the tensors in place", "[distributed]") {
  ScriptedGroup group([](const at::Tensor& t) { return t; });
  torch::nn::Linear lin(3, 2);
  std::vector<at::Tensor> tensors = lin->parameters();
  broadcast_tensors(group, tensors);
  CHECK(torch::equal(lin->weight, torch::full({2, 3}, 7.f)));
  CHECK(torch::equal(lin->bias, torch::full({2}, 7.f)));
  CHECK(lin->weight.requires_grad());
}

TEST_CASE("overlapped reducer: buckets start from autograd hooks during backward, in order; the rest at finish",
          "[distributed]") {
  // The other rank sends what this one sends: the means are this rank's gradients.
  ScriptedGroup group([](const at::Tensor& t) { return t.clone(); });
  torch::manual_seed(0);
  torch::nn::Linear a(4, 8), b(8, 2);
  at::Tensor unused = torch::zeros({3}).requires_grad_(true);  // no gradient on this rank
  std::vector<at::Tensor> params = {unused, a->weight, a->bias, b->weight, b->bias};
  const at::Tensor x = torch::randn({5, 4});
  auto loss_of = [&] { return b->forward(torch::tanh(a->forward(x))).pow(2).sum(); };
  const auto expected = torch::autograd::grad({loss_of()}, {a->weight, a->bias, b->weight, b->bias});
  {
    // Buckets of <= 64 bytes in reverse order: b.bias | b.weight | a.bias | a.weight | unused.
    OverlappedReducer reducer(group, params, GradientSyncOptions{64});
    REQUIRE(reducer.sync().buckets().size() == 5);
    for (int step = 0; step < 2; ++step) {
      for (auto& p : params) p.mutable_grad() = at::Tensor();
      group.sizes.clear();
      reducer.prepare();
      loss_of().backward();
      // The model's four buckets went out while backward ran; `unused`'s waits.
      CHECK(group.sizes == std::vector<int64_t>{3, 17, 9, 33});
      CHECK(reducer.started_in_backward() == 4);
      reducer.finish();
      CHECK(group.sizes == std::vector<int64_t>{3, 17, 9, 33, 4});
      CHECK_FALSE(unused.grad().defined());
      CHECK(torch::allclose(a->weight.grad(), expected[0]));
      CHECK(torch::allclose(a->bias.grad(), expected[1]));
      CHECK(torch::allclose(b->weight.grad(), expected[2]));
      CHECK(torch::allclose(b->bias.grad(), expected[3]));
    }
    // Outside prepare()..finish() the hooks do nothing.
    group.sizes.clear();
    loss_of().backward();
    CHECK(group.sizes.empty());
  }
  // The reducer's hooks left with it.
  loss_of().backward();
  CHECK(group.sizes.empty());
}

TEST_CASE("overlapped reducer: with overlap off, everything is reduced at finish", "[distributed]") {
  ScriptedGroup group([](const at::Tensor& t) { return t.clone(); });
  torch::nn::Linear a(4, 3);
  OverlappedReducer reducer(group, a->parameters(), GradientSyncOptions{16}, /*overlap=*/false);
  reducer.prepare();
  a->forward(torch::ones({2, 4})).sum().backward();
  CHECK(group.sizes.empty());
  reducer.finish();
  CHECK(group.sizes.size() == reducer.sync().buckets().size());
  CHECK(reducer.started_in_backward() == 0);
}

TEST_CASE("overlapped reducer: gradients are views into the buckets, in the parameters' layout, zeroed every step",
          "[distributed]") {
  // The other rank sent twice ours: the mean is 1.5x this rank's gradient.
  ScriptedGroup group([](const at::Tensor& t) { return t * 2; });
  torch::manual_seed(1);
  // A channels-last 5-D weight (the decoder's conv weights on the GPU), a
  // vector, and a parameter no rank uses.
  at::Tensor w = torch::randn({4, 3, 2, 2, 2}).contiguous(at::MemoryFormat::ChannelsLast3d).requires_grad_(true);
  at::Tensor v = torch::randn({3}).requires_grad_(true);
  at::Tensor unused = torch::zeros({2}).requires_grad_(true);
  const at::Tensor x = torch::randn({1, 3, 2, 2, 2});
  auto loss_of = [&] { return ((w * x).sum({1, 2, 3, 4}).sum() * v).sum() + (w * w).sum(); };
  const auto expected = torch::autograd::grad({loss_of()}, {w, v});
  for (const bool overlap : {false, true}) {
    CAPTURE(overlap);
    OverlappedReducer reducer(group, {unused, w, v}, GradientSyncOptions{}, overlap);  // one bucket
    REQUIRE(reducer.sync().buckets().size() == 1);
    for (int step = 0; step < 2; ++step) {
      CAPTURE(step);
      for (auto* p : {&w, &v, &unused}) p->mutable_grad() = at::Tensor();  // the optimiser's zero_grad
      reducer.prepare();
      loss_of().backward();
      reducer.finish();
      // Backward wrote into the bucket itself: both gradients share its storage
      // (a copy back into separate .grad tensors, as before, would not).
      REQUIRE(w.grad().defined());
      REQUIRE(v.grad().defined());
      CHECK(w.grad().storage().is_alias_of(v.grad().storage()));
      CHECK(w.grad().strides() == w.strides());
      CHECK(w.grad().is_contiguous(at::MemoryFormat::ChannelsLast3d));
      // The means of this step alone: the bucket was zeroed in between.
      CHECK(torch::allclose(w.grad(), expected[0] * 1.5));
      CHECK(torch::allclose(v.grad(), expected[1] * 1.5));
      CHECK_FALSE(unused.grad().defined());
    }
  }
}
