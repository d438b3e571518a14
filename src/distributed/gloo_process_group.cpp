#include "distributed/gloo_process_group.h"

#include "flat/core/error.h"

#if __has_include(<gloo/config.h>)
#define FLAT_HAVE_GLOO 1
#ifndef USE_C10D_GLOO
#define USE_C10D_GLOO 1  // the wheel's libtorch_cpu is built with it; its header is guarded by it
#endif
#include <torch/csrc/distributed/c10d/ProcessGroupGloo.hpp>

#include "distributed/c10d_process_group.h"
#else
#define FLAT_HAVE_GLOO 0
#endif

namespace flat::distributed::detail {

bool gloo_available() { return FLAT_HAVE_GLOO != 0; }

#if FLAT_HAVE_GLOO
std::unique_ptr<ProcessGroup> make_gloo_process_group(c10::intrusive_ptr<c10d::Store> store, int64_t rank,
                                                      int64_t world_size, std::chrono::milliseconds timeout) {
  auto opts = c10d::ProcessGroupGloo::Options::create();
  opts->timeout = timeout;
  opts->devices.push_back(c10d::ProcessGroupGloo::createDefaultDevice());
  return make_c10d_process_group<c10d::ProcessGroupGloo>(store, rank, world_size, opts, "gloo");
}
#else
std::unique_ptr<ProcessGroup> make_gloo_process_group(c10::intrusive_ptr<c10d::Store>, int64_t, int64_t,
                                                      std::chrono::milliseconds) {
  fail("distributed: backend gloo needs the gloo headers (Debian package libgloo-dev), which this build did not "
       "find; use store");
}
#endif

}  // namespace flat::distributed::detail
