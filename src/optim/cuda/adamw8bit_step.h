// Launcher of the fused 8-bit AdamW step (adamw8bit_step.cu). Plain header: no
// torch types, so nvcc never parses libtorch.
//
// One launch updates one parameter tensor and its two block-wise quantised
// moments in place: per block of 256 values it dequantises m and v through
// the dynamic maps, does the AdamW update of the parameter, takes the blocks'
// new absmax and writes the nearest codes. The arithmetic is that of the ATen
// reference (AdamW::update_8bit on CUDA) op for op, each scalar rounded to
// float where ATen rounds it, so the two agree bit for bit when ATen's kernels
// round as documented in the .cu file.
#pragma once
#include <cstdint>

#include <cuda_runtime.h>

namespace flat::optim::cuda {

struct AdamW8bitArgs {
  void* param = nullptr;        // numel values, float or bfloat16, contiguous
  const void* grad = nullptr;   // numel values, float or bfloat16, contiguous
  bool param_bf16 = false, grad_bf16 = false;
  uint8_t* m_codes = nullptr;   // blocks * 256 codes each (8-byte aligned)
  uint8_t* v_codes = nullptr;
  float* m_absmax = nullptr;    // blocks values each
  float* v_absmax = nullptr;
  const float* m_map = nullptr;        // signed map: 256 sorted values (device)
  const float* m_midpoints = nullptr;  // its 255 midpoints (device)
  const float* v_map = nullptr;        // unsigned map and its midpoints
  const float* v_midpoints = nullptr;
  float* step = nullptr;  // the parameter's step count (float scalar, device): set to t
  int64_t numel = 0;
  // Scalars, rounded to float as ATen's reference ops round them:
  float t = 0;                // the step number after this update
  float decay = 1;            // 1 - lr * weight_decay
  float lerp_weight = 0.1f;   // 1 - beta1
  float beta2 = 0.999f;
  float one_minus_beta2 = 0.001f;
  float inv_sqrt_bias2 = 1;   // 1 / float(sqrt(1 - beta2^t)) (ATen's reciprocal of a scalar divisor)
  float eps = 1e-8f;
  float step_size = 0;        // -lr / (1 - beta1^t)
};

// Enqueues the update on `stream`; returns the launch's error (cudaSuccess).
cudaError_t launch_adamw8bit_step(const AdamW8bitArgs& args, cudaStream_t stream);

}  // namespace flat::optim::cuda
