// The view's pair count as the preprocessing kernels of the triangles
// (render/cuda/preprocess.cu) and of 3DGS (gaussians/cuda/preprocess.cu)
// gather it: each thread's tile count summed over the block and added to a
// 64-bit total with one atomic a block. CUDA sources only. Public, under
// flat/render/shared/, because gaussians includes it.
#pragma once
#include <cuda_runtime.h>

namespace flat::render::cuda {

// Adds the sum of every thread's `count` in the block of kThreads threads (a
// multiple of 32) to *total; no atomic when it is 0. Every thread calls it.
template <int kThreads>
__device__ __forceinline__ void add_block_sum(long long count, unsigned long long* total) {
  __shared__ long long warp_sums[kThreads / 32];
  long long sum = count;
  for (int d = 16; d > 0; d >>= 1) sum += __shfl_down_sync(0xffffffffu, sum, d);
  if ((threadIdx.x & 31) == 0) warp_sums[threadIdx.x / 32] = sum;
  __syncthreads();
  if (threadIdx.x == 0) {
    long long block_sum = 0;
    for (int w = 0; w < kThreads / 32; ++w) block_sum += warp_sums[w];
    if (block_sum > 0) atomicAdd(total, (unsigned long long)block_sum);
  }
}

}  // namespace flat::render::cuda
