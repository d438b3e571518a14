// Data-parallel gradient averaging: every rank runs the same model on its
// share of the batch; after backward, GradientSync makes every rank's
// gradients the mean over the ranks, so the optimiser steps agree.
//
// The parameters are grouped into buckets of about bucket_bytes of one dtype
// and device each, in reverse parameter order (about the order backward
// produces them); a bucket is one flat tensor, kept for the whole run, and one
// all-reduce. start_bucket(b) starts the bucket's all-reduce without waiting;
// finish_bucket(b) waits and divides by the ranks.
//
// bind_gradients() (before backward) makes every .grad a zeroed alias of its
// slot in the bucket (DDP's gradient_as_bucket_view): backward accumulates
// straight into what the all-reduce sends, and the mean lands in the .grad, so
// a step costs a handful of kernels per bucket, not a copy in and out per
// parameter (those launches, after backward on an idle GPU, were most of the
// 2-GPU overhead). A .grad that is not its bucket alias (never bound, or
// replaced by the caller) is copied in and the mean copied back.
//
// A parameter without a gradient on a rank (unused in its forward)
// contributes zeros, so every rank still makes the same collectives. Each
// bucket carries one presence count per parameter: a parameter that had a
// gradient on no rank keeps an undefined gradient everywhere (as in one
// process, where the optimiser then skips it); otherwise every rank gets the
// mean, zeros included. A bound alias is always defined: it counts as present
// when something wrote to it since bind_gradients (its version counter moved;
// AccumulateGrad adds into it in place).
#pragma once
#include <cstdint>
#include <memory>
#include <vector>

#include <ATen/ATen.h>

#include "flat/distributed/process_group.h"

namespace flat::distributed {

// Makes every rank's `tensors` (parameters and buffers, in the same order on
// every rank) rank `root`'s values; one broadcast per tensor, no autograd.
void broadcast_tensors(ProcessGroup& group, const std::vector<at::Tensor>& tensors, int64_t root = 0);

struct GradientSyncOptions {
  int64_t bucket_bytes = 25ll << 20;  // PyTorch DDP's default bucket size
  // Send float gradients as bf16 (half the bytes; PyTorch DDP's
  // bf16_compress_hook): each bucket is cast to bf16 for the all-reduce, and
  // the mean cast back into the gradients (about 3 significant digits).
  bool bf16_wire = false;
};

class GradientSync {
 public:
  struct Bucket {
    std::vector<int64_t> params;  // indices into the parameter list
    int64_t numel = 0;             // gradient values and alignment padding (then one count per parameter)
    std::vector<int64_t> offsets;  // where each parameter's values start, 16-byte aligned
  };

  // `params`: the trainable parameters, in the same order on every rank.
  GradientSync(ProcessGroup& group, std::vector<at::Tensor> params, GradientSyncOptions options = {});

  // Before backward, with no bucket in flight: zeroes the buckets and makes
  // each parameter's .grad an alias of its slot, with the parameter's strides
  // (a bf16 wire then casts the whole bucket in one kernel).
  void bind_gradients();
  // After backward: every bucket started in order, then every one finished
  // (the all-reduces of earlier buckets overlap the starting of later ones).
  void all_reduce_gradients();
  void reduce_bucket(size_t b);  // start_bucket(b), finish_bucket(b)

  // Every rank must start the buckets in the same order; the gradients of a
  // started bucket must not change until it is finished.
  void start_bucket(size_t b);
  void finish_bucket(size_t b);
  bool started(size_t b) const { return pending_.at(b).work != nullptr; }

  const std::vector<Bucket>& buckets() const { return buckets_; }
  const std::vector<at::Tensor>& params() const { return params_; }

 private:
  struct Pending {
    at::Tensor wire;  // what the all-reduce sends: the bucket, or its bf16 copy
    std::unique_ptr<Work> work;
    bool all_present = true;  // every parameter had a gradient here
    bool all_bound = true;    // and each one is its bucket view: nothing to copy back
  };
  // Whether `param`'s .grad is its own bucket view (the very tensor bind_gradients set).
  bool is_bound(int64_t param) const;
  ProcessGroup& group_;
  std::vector<at::Tensor> params_;
  std::vector<Bucket> buckets_;
  std::vector<Pending> pending_;
  std::vector<at::Tensor> flat_;  // per bucket: [gradients..., presence counts], the parameters' dtype
  std::vector<at::Tensor> views_;      // per parameter: its slot in flat_ (an alias), with the parameter's strides
  std::vector<int64_t> bound_version_;  // per parameter: its alias's version when bind_gradients set it
  bool bf16_wire_ = false;
};

}  // namespace flat::distributed
