// Peak device memory of the CUDA caching allocator, for benchmarks (0 on the
// CPU and in builds without CUDA).
#pragma once
#include <c10/core/Device.h>

namespace flat {

void reset_peak_memory(const c10::Device& device);
// Peak bytes allocated since the last reset, in GiB.
double peak_memory_gib(const c10::Device& device);

}  // namespace flat
