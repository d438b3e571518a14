// The timing helpers every benchmark shares (flat_bench's subcommands and the
// training-step benchmark): wall-clock milliseconds, the median of repeats,
// and a device synchronisation so that a time covers the GPU's work.
#pragma once
#include <vector>

#include <ATen/ATen.h>

namespace flat::bench {

double now_ms();                          // steady clock, milliseconds
double median(std::vector<double> v);     // upper median; 0 for no values
void sync_device(const at::Device& d);    // waits for the CUDA device's work (no-op on the CPU)

}  // namespace flat::bench
