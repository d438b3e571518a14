// Launcher of the Hopper (sm_90a) implicit-GEMM 3D convolution built on CUTLASS
// 3 (TMA im2col loads + warpgroup MMA). Plain header: no torch, no CUTLASS
// types, so only conv3d_sm90.cu pays CUTLASS's compile time.
#pragma once
#include <cstddef>

#include <cuda_runtime.h>

namespace flat::model::cuda {

// out = conv3d(x, w) + bias[k] (+ residual), bf16 in and out, fp32 accumulation.
// x: (n,d,h,w,c) channels-last contiguous; w: (k,t,r,s,c) contiguous; bias:
// k values or null; residual and out: (n,z,p,q,k) contiguous; every pointer
// 16-byte aligned (TMA). Stride 1, dilation 1, zero padding
// pad_* on both sides of each spatial axis (the causal time padding is
// written into x by the caller, so pad_d is 0 there).
struct Conv3dProblem {
  int n = 0, d = 0, h = 0, w = 0, c = 0;
  int k = 0, t = 0, r = 0, s = 0;
  int pad_d = 0, pad_h = 0, pad_w = 0;
  int out_d() const { return d + 2 * pad_d - t + 1; }
  int out_h() const { return h + 2 * pad_h - r + 1; }
  int out_w() const { return w + 2 * pad_w - s + 1; }
};

// The compiled tile configurations ("128x192x64": output pixels x output
// channels x input channels per step).
int conv3d_sm90_config_count();
const char* conv3d_sm90_config_name(int config);
// Whether `config` can run `p` (alignment, channel divisibility, TMA limits).
bool conv3d_sm90_can_run(int config, const Conv3dProblem& p);
// Scratch bytes the config needs for `p` (0 for these kernels, asked anyway).
size_t conv3d_sm90_workspace_bytes(int config, const Conv3dProblem& p);
// Runs the conv on `stream`. residual may be null. Returns false (and launches
// nothing) if CUTLASS refuses the problem; a launch error is returned as false too.
bool conv3d_sm90_run(int config, const Conv3dProblem& p, const void* x, const void* w, const void* bias,
                     const void* residual, void* out, void* workspace, cudaStream_t stream);

}  // namespace flat::model::cuda
