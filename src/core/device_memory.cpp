#include "flat/core/device_memory.h"

#if FLAT_WITH_CUDA
#include <c10/cuda/CUDACachingAllocator.h>
#endif

namespace flat {

void reset_peak_memory(const c10::Device& d) {
#if FLAT_WITH_CUDA
  if (d.is_cuda()) c10::cuda::CUDACachingAllocator::resetPeakStats(d.index() < 0 ? 0 : d.index());
#else
  (void)d;
#endif
}

double peak_memory_gib(const c10::Device& d) {
#if FLAT_WITH_CUDA
  if (d.is_cuda()) {
    auto stats = c10::cuda::CUDACachingAllocator::getDeviceStats(d.index() < 0 ? 0 : d.index());
    return double(stats.allocated_bytes[size_t(c10::CachingAllocator::StatType::AGGREGATE)].peak) / double(1ull << 30);
  }
#else
  (void)d;
#endif
  return 0.0;
}

}  // namespace flat
