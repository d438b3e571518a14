// The "nccl" backend (process_group.h): c10d::ProcessGroupNCCL, CUDA builds only.
#pragma once
#include <chrono>
#include <memory>

#include <torch/csrc/distributed/c10d/Store.hpp>

#include "flat/distributed/process_group.h"

namespace flat::distributed::detail {

// Throws flat::Error in a build without CUDA.
std::unique_ptr<ProcessGroup> make_nccl_process_group(c10::intrusive_ptr<c10d::Store> store, int64_t rank,
                                                      int64_t world_size, std::chrono::milliseconds timeout);

}  // namespace flat::distributed::detail
