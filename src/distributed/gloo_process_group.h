// The "gloo" backend (process_group.h): c10d::ProcessGroupGloo, PyTorch's CPU
// collectives. The torch wheel holds its code but not the gloo headers that
// its header includes; Debian's libgloo-dev provides them (checked: an
// allreduce between two processes gives the right sums with them).
#pragma once
#include <chrono>
#include <cstdint>
#include <memory>

#include <torch/csrc/distributed/c10d/Store.hpp>

#include "flat/distributed/process_group.h"

namespace flat::distributed::detail {

// True when this build found the gloo headers (FLAT_HAVE_GLOO).
bool gloo_available();
// Throws flat::Error in a build without the gloo headers.
std::unique_ptr<ProcessGroup> make_gloo_process_group(c10::intrusive_ptr<c10d::Store> store, int64_t rank,
                                                      int64_t world_size, std::chrono::milliseconds timeout);

}  // namespace flat::distributed::detail
