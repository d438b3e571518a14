// Data-parallel gradient averaging: every rank runs the same model on its
// share of the batch; after backward, GradientSync makes every rank's
// gradients the mean over the ranks, so the optimiser steps agree.
//
// The parameters are grouped into buckets of about bucket_bytes of one dtype
// and device each, in reverse parameter order (about the order backward
// produces them); a bucket is one flat tensor and one all-reduce.
// start_bucket(b) copies the bucket's gradients in and starts its all-reduce
// without waiting; finish_bucket(b) waits and writes the means back.
// OverlappedReducer (overlapped_reducer.h) starts buckets from autograd hooks
// while backward still runs.
//
// A parameter without a gradient on a rank (unused in its forward)
// contributes zeros, so every rank still makes the same collectives. Each
// bucket carries one presence count per parameter: a parameter that had a
// gradient on no rank keeps an undefined gradient everywhere (as in one
// process, where the optimiser then skips it); otherwise every rank gets the
// mean, zeros included.
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
    int64_t numel = 0;            // gradient values (the flat tensor adds one count per parameter)
  };

  // `params`: the trainable parameters, in the same order on every rank.
  GradientSync(ProcessGroup& group, std::vector<at::Tensor> params, GradientSyncOptions options = {});

  // After backward: every bucket started in order, then every one finished
  // (the all-reduces of later buckets overlap the copies of earlier ones).
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
    at::Tensor flat;  // [gradients..., presence counts]
    std::unique_ptr<Work> work;
  };
  ProcessGroup& group_;
  std::vector<at::Tensor> params_;
  std::vector<Bucket> buckets_;
  std::vector<Pending> pending_;
  bool bf16_wire_ = false;
};

}  // namespace flat::distributed
