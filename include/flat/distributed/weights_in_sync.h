// Whether every rank of a data-parallel job still holds the same weights.
// Ranks start from rank 0's weights and apply the same all-reduced gradients,
// so their weights must stay bit-identical; if they drift (a rank that
// stepped differently, an optimiser state that differs), rank 0's checkpoint
// and the validation that every rank scores with its own copy no longer
// describe one model. Each rank fingerprints every tensor (its fp64 sum and
// sum of squares), compares with rank 0's and learns which ranks differ.
#pragma once
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <ATen/ATen.h>

#include "flat/distributed/process_group.h"

namespace flat::distributed {

struct WeightsSync {
  std::vector<int64_t> differing_ranks;  // empty: every rank holds rank 0's weights
  // Here, when this rank differs: the first differing tensor and its fingerprint beside rank 0's.
  std::string first_tensor;
  double here_sum = 0, rank0_sum = 0;
  bool in_sync() const { return differing_ranks.empty(); }
};

// A collective: every rank calls it with its tensors named in the same order.
WeightsSync check_weights_in_sync(ProcessGroup& group, const std::vector<std::pair<std::string, at::Tensor>>& named);

}  // namespace flat::distributed
