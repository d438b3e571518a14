// A batch of staged PixelTri records in shared memory, stored field-major
// (structure of arrays): field f of triangle j at v[f][j]. In the compositing
// kernels different threads read different triangles (a thread per staged
// triangle, or a pixel reading its own hits); with records laid out one after
// another (24 words each) triangles j and j + 4 share banks and the reads
// serialise up to 8 ways, while field-major reads hit distinct banks.
#pragma once
#include "render/triangle_math.h"

namespace flat::render::cuda {

template <int Batch>
struct SharedTris {
  static constexpr int kFields = sizeof(PixelTri<float>) / sizeof(float);
  float v[kFields][Batch];

  __device__ __forceinline__ void put(int j, const PixelTri<float>& t) {
    const float* f = reinterpret_cast<const float*>(&t);
#pragma unroll
    for (int i = 0; i < kFields; ++i) v[i][j] = f[i];
  }
  __device__ __forceinline__ PixelTri<float> get(int j) const {
    PixelTri<float> t;
    float* f = reinterpret_cast<float*>(&t);
#pragma unroll
    for (int i = 0; i < kFields; ++i) f[i] = v[i][j];
    return t;
  }
};

}  // namespace flat::render::cuda
