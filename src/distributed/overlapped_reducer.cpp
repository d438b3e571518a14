#include "flat/distributed/overlapped_reducer.h"

#include <torch/csrc/autograd/function_hook.h>
#include <torch/csrc/autograd/variable.h>

#include "flat/core/error.h"

namespace flat::distributed {
namespace {

// Runs in the autograd engine right after AccumulateGrad has written the
// parameter's .grad for this backward.
class ReadyHook : public torch::autograd::PostAccumulateGradHook {
 public:
  ReadyHook(OverlappedReducer* reducer, int64_t param) : reducer_(reducer), param_(param) {}
  void operator()(const torch::autograd::Variable&) override { reducer_->mark_ready(param_); }

 private:
  OverlappedReducer* reducer_;
  int64_t param_;
};

}  // namespace

OverlappedReducer::OverlappedReducer(ProcessGroup& group, std::vector<at::Tensor> params,
                                     GradientSyncOptions options, bool overlap)
    : sync_(group, std::move(params), options), overlap_(overlap) {
  const auto& ps = sync_.params();
  bucket_of_.assign(ps.size(), -1);
  waiting_.assign(sync_.buckets().size(), 0);
  ready_.assign(ps.size(), 0);
  for (size_t b = 0; b < sync_.buckets().size(); ++b)
    for (int64_t i : sync_.buckets()[b].params) bucket_of_[size_t(i)] = int64_t(b);
  if (!overlap_) return;
  for (size_t i = 0; i < ps.size(); ++i) {
    FLAT_CHECK(ps[i].is_leaf() && ps[i].requires_grad(),
               "overlapped reducer: parameter " + std::to_string(i) + " is not a leaf that requires grad");
    torch::autograd::impl::set_post_acc_grad_hooks(ps[i], std::make_unique<ReadyHook>(this, int64_t(i)));
  }
}

OverlappedReducer::~OverlappedReducer() {
  if (!overlap_) return;
  for (const auto& p : sync_.params()) torch::autograd::impl::set_post_acc_grad_hooks(p, nullptr);
}

void OverlappedReducer::prepare() {
  std::lock_guard<std::mutex> lock(mutex_);
  sync_.bind_gradients();
  for (size_t b = 0; b < waiting_.size(); ++b) waiting_[b] = int64_t(sync_.buckets()[b].params.size());
  std::fill(ready_.begin(), ready_.end(), 0);
  next_start_ = 0;
  started_in_backward_ = 0;
  error_.clear();
  armed_ = overlap_;
}

void OverlappedReducer::mark_ready(int64_t param) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!armed_) return;  // a backward outside a training step (none today): not ours to reduce
  const int64_t b = bucket_of_[size_t(param)];
  if (ready_[size_t(param)]) {
    // A second accumulation into the same .grad in one backward (a parameter
    // used by two separately differentiated graphs): fine until its bucket
    // has started, wrong after.
    if (size_t(b) < next_start_ && error_.empty())
      error_ = "overlapped reducer: parameter " + std::to_string(param) +
               " received a second gradient after its bucket's all-reduce had started; set "
               "distributed.overlap: false";
    return;
  }
  ready_[size_t(param)] = 1;
  if (--waiting_[size_t(b)] == 0) start_ready_buckets();
}

void OverlappedReducer::start_ready_buckets() {
  while (next_start_ < waiting_.size() && waiting_[next_start_] == 0) {
    sync_.start_bucket(next_start_++);
    ++started_in_backward_;
  }
}

void OverlappedReducer::finish() {
  std::lock_guard<std::mutex> lock(mutex_);
  armed_ = false;
  // What no hook started, in order: buckets with a parameter that has no
  // gradient on this rank, or all of them when this rank skipped backward.
  for (size_t b = next_start_; b < waiting_.size(); ++b) sync_.start_bucket(b);
  next_start_ = waiting_.size();
  for (size_t b = 0; b < waiting_.size(); ++b) sync_.finish_bucket(b);
  FLAT_CHECK(error_.empty(), error_);
}

}  // namespace flat::distributed
