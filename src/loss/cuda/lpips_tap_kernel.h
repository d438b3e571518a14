// Launchers of the fused LPIPS tap kernels. Plain header: no torch types, so
// nvcc never parses libtorch.
#pragma once
#include <cstdint>

#include <cuda_runtime.h>

namespace flat::loss::cuda {

// Whether the kernels take `channels` bf16 channels per pixel (a multiple of
// 8 up to 512: VGG's 64, 128, 256 and 512).
bool lpips_tap_supported(int64_t channels);

// a, b: rows x channels bf16 (channels-last features, one row per pixel), w:
// channels floats. pixel_out[r] = sum_c w_c (a_c/(|a|+1e-10) - b_c/(|b|+1e-10))^2.
void launch_lpips_tap_forward(const void* a, const void* b, const float* w, float* pixel_out, int64_t rows,
                              int64_t channels, cudaStream_t stream);

// The gradient of sum_r scale[r / pixels_per_view] * pixel_out[r] with
// respect to a (into grad_a) and, when grad_b is not null, b. bf16 outputs.
void launch_lpips_tap_backward(const void* a, const void* b, const float* w, const float* scale, void* grad_a,
                               void* grad_b, int64_t rows, int64_t pixels_per_view, int64_t channels,
                               cudaStream_t stream);

}  // namespace flat::loss::cuda
