// Gradient averaging overlapped with backward (what DDP's reducer does): a
// post-accumulate-grad hook on every parameter (libtorch's
// torch::autograd::impl::set_post_acc_grad_hooks, the C++ side of Python's
// register_post_accumulate_grad_hook) marks it ready once its gradient for
// this backward is complete; when every parameter of a bucket is ready the
// bucket's all-reduce starts (GradientSync::start_bucket, asynchronous on
// gloo and nccl) while backward goes on with the earlier layers. finish()
// starts what is left (buckets holding a parameter without a gradient on
// this rank, or everything after a skipped backward) and waits for all.
//
// Buckets start strictly in index order on every rank (a ready bucket waits
// for the ones before it), so the ranks issue the same collectives in the
// same order whatever order their hooks fire in.
//
// prepare() binds every .grad to its bucket (GradientSync::bind_gradients),
// so backward accumulates into the buckets. With overlap off the hooks are not
// installed and finish() is GradientSync::all_reduce_gradients after backward.
#pragma once
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <ATen/ATen.h>

#include "flat/distributed/gradient_sync.h"

namespace flat::distributed {

class OverlappedReducer {
 public:
  // `params`: the trainable parameters (leaves that require grad), in the same
  // order on every rank. Installs the hooks (replacing any other
  // post-accumulate-grad hook on them); the destructor removes them.
  OverlappedReducer(ProcessGroup& group, std::vector<at::Tensor> params, GradientSyncOptions options = {},
                    bool overlap = true);
  ~OverlappedReducer();
  OverlappedReducer(const OverlappedReducer&) = delete;
  OverlappedReducer& operator=(const OverlappedReducer&) = delete;

  // Before the forward of a step, after the optimiser dropped the gradients:
  // binds them to the buckets; the hooks act only between prepare() and finish().
  void prepare();
  // After backward (or when this rank skipped it): every parameter's gradient
  // is the mean over the ranks (none where no rank had one).
  void finish();

  // Buckets whose all-reduce started from a hook during the last backward.
  int64_t started_in_backward() const { return started_in_backward_; }
  const GradientSync& sync() const { return sync_; }

  // Called by the hooks.
  void mark_ready(int64_t param);

 private:
  void start_ready_buckets();  // caller holds mutex_

  GradientSync sync_;
  bool overlap_;
  std::vector<int64_t> bucket_of_;    // parameter -> bucket
  std::vector<int64_t> waiting_;      // per bucket: parameters not yet ready
  std::vector<char> ready_;           // per parameter, this backward
  size_t next_start_ = 0;             // buckets start in order
  bool armed_ = false;
  int64_t started_in_backward_ = 0;
  std::string error_;                 // a hook's complaint, thrown by finish()
  std::mutex mutex_;
};

}  // namespace flat::distributed
