// The "store" backend (process_group.h): collectives through a c10d::Store.
#pragma once
#include <chrono>
#include <memory>

#include <torch/csrc/distributed/c10d/Store.hpp>

#include "flat/distributed/process_group.h"

namespace flat::distributed::detail {

std::unique_ptr<ProcessGroup> make_store_process_group(c10::intrusive_ptr<c10d::Store> store, int64_t rank,
                                                       int64_t world_size, std::chrono::milliseconds timeout);

}  // namespace flat::distributed::detail
