// The transcendental functions of the rasterizers' per-(pixel, primitive)
// loops: on the GPU (float) the hardware approximations, exact on the CPU
// (the references, float or double). Plain C++ with __host__ __device__ under
// nvcc (FLAT_HD). Public, under flat/render/shared/, because gaussians and
// surfels include it.
//   fast_exp    a Gaussian's falloff (3DGS, 2DGS): __expf, a few ulp over the
//               kept range (q <= 9, rho <= 11);
//   window_pow, window_log  the triangle window (ex2/lg2, a few ulp; the
//               accurate powf costs ~40 instructions);
//   fast_div    a / b, the 2-ulp division (the IEEE one is ~10 instructions);
//   fast_rsqrt  1 / sqrt(x), the 2-ulp reciprocal square root (the IEEE
//               square root and division are ~30 instructions).
// The CUDA-vs-CPU tolerances of docs/rasterizer*.md hold with them.
#pragma once
#include <cmath>

#include "flat/render/shared/compositing.h"  // FLAT_HD

namespace flat::render {

// double: the CPU references' finite-difference runs.
FLAT_HD double fast_exp(double x) { return std::exp(x); }
FLAT_HD double window_pow(double x, double y) { return std::pow(x, y); }
FLAT_HD double window_log(double x) { return std::log(x); }
FLAT_HD double fast_div(double a, double b) { return a / b; }
FLAT_HD double fast_rsqrt(double x) { return 1.0 / std::sqrt(x); }

// float: the hardware approximations on the GPU, exact on the CPU.
#if defined(__CUDA_ARCH__)
FLAT_HD float fast_exp(float x) { return __expf(x); }
FLAT_HD float window_pow(float x, float y) { return __powf(x, y); }
FLAT_HD float window_log(float x) { return __logf(x); }
FLAT_HD float fast_div(float a, float b) { return __fdividef(a, b); }
FLAT_HD float fast_rsqrt(float x) { return rsqrtf(x); }
#else
FLAT_HD float fast_exp(float x) { return std::exp(x); }
FLAT_HD float window_pow(float x, float y) { return std::pow(x, y); }
FLAT_HD float window_log(float x) { return std::log(x); }
FLAT_HD float fast_div(float a, float b) { return a / b; }
FLAT_HD float fast_rsqrt(float x) { return 1.f / std::sqrt(x); }
#endif

}  // namespace flat::render
