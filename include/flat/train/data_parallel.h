// One rank of a data-parallel training run as the trainer sees it (docs/
// training.md, Multi-GPU): the process group (distributed.backend, .timeout),
// rank 0's weights shared at the start, gradients averaged over the ranks in
// buckets overlapped with backward (distributed.overlap, .bucket_mb), and the
// step's figures and decisions agreed by all ranks, so that every rank takes
// the same branch and none waits in a collective the others skipped:
//
//   - a step is skipped when its loss or gradient is not finite on any rank;
//   - the run stops (checkpoint, exit 128 + signal) when any rank got
//     SIGINT/SIGTERM;
//   - the logged loss terms are the mean over the ranks, the triangle count
//     the sum (one process on the whole batch logs the same).
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <ATen/ATen.h>

#include "flat/distributed/distributed_env.h"
#include "flat/distributed/overlapped_reducer.h"
#include "flat/distributed/process_group.h"
#include "flat/train/train_config.h"
#include "flat/train/train_step.h"

namespace torch::nn {
class Module;
}

namespace flat::train {

// "auto" -> nccl on CUDA, gloo on the CPU (store in a build without the gloo headers).
std::string resolve_backend(const std::string& backend, const at::Device& device);

class DataParallel {
 public:
  // Rendezvous of env.world_size ranks on `device` (cuda:LOCAL_RANK, made the
  // current device by the caller, or the CPU); the heartbeats start.
  DataParallel(const DistributedConfig& config, const distributed::DistributedEnv& env, const at::Device& device);

  int64_t rank() const { return group_->rank(); }
  int64_t world_size() const { return group_->world_size(); }
  distributed::ProcessGroup& group() { return *group_; }
  const std::string& backend() const { return backend_; }

  // Rank 0's parameters and buffers on every rank (after init and resume).
  void share_weights(torch::nn::Module& model);
  // Throws flat::Error naming the ranks whose parameters or buffers are no
  // longer bit-identical to rank 0's (distributed/weights_in_sync.h), with
  // `when` ("step 80") in the message. Every rank calls it.
  void check_weights_in_sync(torch::nn::Module& model, const std::string& when);
  // Rank 0's value of `value` (e.g. the step a resumed run continues at).
  int64_t broadcast(int64_t value);

  // From now on the gradients of `params` (trainable, same order on every
  // rank) are averaged: hooks installed when distributed.overlap is on.
  void reduce_gradients_of(std::vector<at::Tensor> params);
  void before_backward();  // arms the hooks
  void after_backward();   // the rest of the buckets; every gradient is now the mean
  int64_t buckets() const;
  int64_t started_in_backward() const;

  // Agrees on the step (see above): `result` becomes the step over all ranks;
  // returns the stop signal that any rank asked for (0: none).
  int agree(StepResult& result, int stop_signal);
  std::vector<double> sum(const std::vector<double>& values);

  // The clean end (every rank): rank 0 outlives the others' use of its store.
  void finish();

 private:
  std::string backend_;
  at::Device device_;
  distributed::GradientSyncOptions sync_options_;
  bool overlap_;
  std::unique_ptr<distributed::ProcessGroup> group_;
  std::unique_ptr<distributed::OverlappedReducer> reducer_;
};

}  // namespace flat::train
