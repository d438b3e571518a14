// Front-to-back alpha compositing as the three rasterizers (triangles in
// render, 3DGS in gaussians, 2DGS in surfels) all do it: the constants, the
// rules each fragment meets, and the depth order of the primitives. Each
// primitive supplies only its falloff (the triangle's window, a Gaussian's
// exp(-q/2)); what happens to the alpha it gives is written here once, for
// the CPU references (templated on float/double) and the CUDA kernels (float).
// Plain C++ with __host__ __device__ under nvcc: no torch, no std containers.
// Public, under flat/render/shared/, because gaussians and surfels include
// it; an edit here changes all three rasterizers (docs/rasterizer.md,
// "Constants", lists them).
#pragma once
#include <cstdint>
#include <cstring>

#if defined(__CUDACC__)
#define FLAT_HD __host__ __device__ __forceinline__
#else
#define FLAT_HD inline
#endif

namespace flat::render {

// The defaults of the compositing settings: render::CompositingSettings
// (double, from YAML) and CompositingConstants (float, in the kernels) both
// start from these.
inline constexpr double kDefaultNearPlane = 0.01;         // metres
inline constexpr double kDefaultAlphaMax = 0.99;          // keeps 1 - alpha invertible in the backward
inline constexpr double kDefaultAlphaMin = 1.0 / 255.0;   // below one 8-bit step a fragment is skipped
inline constexpr double kDefaultTransmittanceMin = 1e-4;  // a pixel stops before T drops below this
// The median depth is the depth of the fragment that takes the transmittance
// across this value.
inline constexpr double kMedianTransmittance = 0.5;

// The compositing constants of one rasterization, as the kernels read them.
// The triangle rasterizer's RasterConstants adds its window's; 3DGS and 2DGS
// use these alone.
struct CompositingConstants {
  float near_plane = float(kDefaultNearPlane);  // a primitive nearer than this is culled
  float alpha_max = float(kDefaultAlphaMax);    // alpha cap
  float alpha_min = float(kDefaultAlphaMin);    // a fragment with alpha below this is skipped
  float t_min = float(kDefaultTransmittanceMin);  // a pixel stops before its transmittance would drop below this
};

template <class T> FLAT_HD T tmin(T a, T b) { return a < b ? a : b; }
template <class T> FLAT_HD T tmax(T a, T b) { return a > b ? a : b; }

// ---------------------------------------------------------------- fragment rules
// A primitive of this opacity can never reach alpha_min: culled before its
// projection (false for NaN).
template <class T>
FLAT_HD bool opacity_can_blend(T opacity, const CompositingConstants& k) {
  return !(k.alpha_min > 0.f) || opacity >= T(k.alpha_min);
}

// The alpha of a fragment: opacity times the primitive's falloff at the
// pixel, capped at alpha_max.
template <class T>
FLAT_HD T fragment_alpha(T opacity, T falloff, const CompositingConstants& k) {
  return tmin(T(k.alpha_max), opacity * falloff);
}

// Below the cap alpha = opacity * falloff and its gradient reaches both; at
// the cap alpha is flat.
template <class T>
FLAT_HD bool below_alpha_cap(T opacity, T falloff, const CompositingConstants& k) {
  return opacity * falloff < T(k.alpha_max);
}

// Whether a fragment of this alpha is composited: alpha >= alpha_min and > 0
// (false for NaN).
template <class T>
FLAT_HD bool fragment_blends(T alpha, const CompositingConstants& k) {
  return alpha >= T(k.alpha_min) && alpha > T(0);
}

// Whether a pixel stops before a fragment that would leave it this
// transmittance (the fragment is not composited).
template <class T>
FLAT_HD bool stops_before(T transmittance_after, const CompositingConstants& k) {
  return transmittance_after < T(k.t_min);
}

// ---------------------------------------------------------------- depth order
// The depth sort's key of a (positive) primitive depth: its float bits, which
// order as the floats, less the lowest 7: depths within 2^-16 of each other
// (0.08 mm at 5 m) tie and keep index order. 24-bit keys take one radix pass
// fewer than 32-bit ones (the tile binning, render/cuda/binning.cu).
constexpr int kDepthKeyBits = 24;
FLAT_HD uint32_t depth_sort_key(float depth) {
  uint32_t bits;
#if defined(__CUDA_ARCH__)
  bits = __float_as_uint(depth);
#else
  std::memcpy(&bits, &depth, sizeof bits);
#endif
  return bits >> (31 - kDepthKeyBits);  // bit 31 (the sign) is 0
}

}  // namespace flat::render
