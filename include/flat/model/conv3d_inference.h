// The decoder's 3D convolutions without autograd: conv3d(x, w) + bias
// (+ residual). On an sm_90 GPU with bf16 channels-last tensors this picks,
// once per problem shape, the fastest of cuDNN and the CUTLASS implicit-GEMM
// kernels of src/model/cuda_sm90 (each timed on first use, like cuDNN's own
// benchmark mode); the CUTLASS kernels also fuse the residual add into the
// conv's epilogue. Everywhere else (CPU, fp32, autograd, other GPUs, builds
// without CUTLASS) it is at::conv3d (+ add).
#pragma once
#include <array>
#include <cstdint>
#include <string>

#include <ATen/ATen.h>

namespace flat::model {

// x (B,C,T,H,W), weight (K,C,kt,kh,kw), bias (K) or undefined; stride 1,
// symmetric zero padding `padding` per axis; residual (B,K,T',H',W') or
// undefined, added to the result. Differentiable through the at::conv3d path.
at::Tensor conv3d_inference(const at::Tensor& x, const at::Tensor& weight, const at::Tensor& bias,
                            std::array<int64_t, 3> padding, const at::Tensor& residual = {});

// Whether the CUTLASS kernels were compiled in and this process may use them
// (switch for benchmarks and tests; on by default).
bool cutlass_conv_compiled();
void set_cutlass_conv_enabled(bool enabled);
// Forces one CUTLASS configuration for every eligible conv (by name, e.g.
// "128x192x64"), "cudnn" for none, or "" for the per-shape timing (default).
// Unknown names throw.
void set_cutlass_conv_choice(const std::string& name);
// One line per problem shape timed so far: shape, each candidate's ms, choice.
std::string cutlass_conv_report();
// What ran the last conv3d_inference call of this thread: "cudnn" (also for
// the CPU and autograd) or the CUTLASS configuration's name.
std::string conv3d_inference_last_path();

}  // namespace flat::model
