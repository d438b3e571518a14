// The decoder's 3D convolutions without autograd: conv3d(x, w) + bias
// (+ residual). On an sm_90 GPU with bf16 channels-last tensors this picks,
// once per problem shape, the fastest of cuDNN and the CUTLASS implicit-GEMM
// kernels of src/model/cuda_sm90 (each timed on first use, like cuDNN's own
// benchmark mode); the CUTLASS kernels also fuse the residual add into the
// conv's epilogue. Everywhere else (CPU, fp32, autograd, other GPUs, builds
// without CUTLASS) it is at::conv3d (+ add). Which of them may run is the
// caller's `backend` (KernelChoices::conv_backend, a member of the modules).
#pragma once
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <ATen/ATen.h>

#include "flat/core/config.h"

namespace flat::model {

// x (B,C,T,H,W), weight (K,C,kt,kh,kw), bias (K) or undefined; stride 1,
// symmetric zero padding `padding` per axis; residual (B,K,T',H',W') or
// undefined, added to the result. Differentiable through the at::conv3d path.
// backend: "auto" (the per-shape timing: the fastest of cuDNN and the CUTLASS
// configurations), "cudnn" (never CUTLASS), or one CUTLASS configuration by
// name (e.g. "128x192x64"; cuDNN where that one cannot run the problem).
// Unknown names throw (check_conv_backend).
at::Tensor conv3d_inference(const at::Tensor& x, const at::Tensor& weight, const at::Tensor& bias,
                            std::array<int64_t, 3> padding, const at::Tensor& residual = {},
                            const std::string& backend = "auto");

// Whether the CUTLASS kernels were compiled in.
bool cutlass_conv_compiled();
// The names `backend` may take in this build: auto, cudnn, then the CUTLASS
// configurations (none without CUTLASS).
std::vector<std::string> conv_backends();
// Throws flat::Error naming the valid backends when `name` is none of them.
void check_conv_backend(const std::string& name);
// The same rule as a config check (KernelChoices::conv_backend).
config::Check conv_backend_check();
// One line per problem shape timed so far: shape, each candidate's ms, choice.
// (A cache of measurements, shared by all modules: not a choice.)
std::string cutlass_conv_report();
// What ran the last conv3d_inference call of this thread: "cudnn" (also for
// the CPU and autograd) or the CUTLASS configuration's name.
std::string conv3d_inference_last_path();

}  // namespace flat::model
