// Data-parallel gradient averaging: every rank runs the same model on its
// share of the batch; after backward, GradientSync makes every rank's
// gradients the mean over the ranks, so the optimiser steps agree.
//
// The parameters are grouped into buckets of about bucket_bytes of one dtype
// and device each, in reverse parameter order (the order backward produces
// them, for the overlapped reducer to come); a bucket is one flat tensor and
// one all-reduce. reduce_bucket(b) is public so that a later reducer can
// launch a bucket from autograd hooks as soon as its gradients are ready.
//
// A parameter without a gradient on a rank (unused in its forward)
// contributes zeros, so every rank still makes the same collectives. Each
// bucket carries one presence count per parameter: a parameter that had a
// gradient on no rank keeps an undefined gradient everywhere (as in one
// process, where the optimiser then skips it); otherwise every rank gets the
// mean, zeros included.
#pragma once
#include <cstdint>
#include <vector>

#include <ATen/ATen.h>

#include "flat/distributed/process_group.h"

namespace flat::distributed {

// Makes every rank's `tensors` (parameters and buffers, in the same order on
// every rank) rank `root`'s values; one broadcast per tensor, no autograd.
void broadcast_tensors(ProcessGroup& group, const std::vector<at::Tensor>& tensors, int64_t root = 0);

struct GradientSyncOptions {
  int64_t bucket_bytes = 25ll << 20;  // PyTorch DDP's default bucket size
};

class GradientSync {
 public:
  struct Bucket {
    std::vector<int64_t> params;  // indices into the parameter list
    int64_t numel = 0;            // gradient values (the flat tensor adds one count per parameter)
  };

  // `params`: the trainable parameters, in the same order on every rank.
  GradientSync(ProcessGroup& group, std::vector<at::Tensor> params, GradientSyncOptions options = {});

  // After backward: every bucket, in order.
  void all_reduce_gradients();
  void reduce_bucket(size_t b);

  const std::vector<Bucket>& buckets() const { return buckets_; }

 private:
  ProcessGroup& group_;
  std::vector<at::Tensor> params_;
  std::vector<Bucket> buckets_;
};

}  // namespace flat::distributed
