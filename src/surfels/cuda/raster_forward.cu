// Forward compositing: one block per tile (kTileSize x kTileSize: 16 x 16 as shipped), one thread per pixel. The
// block reads the tile's depth-sorted list in rounds of kBlockSize surfels
// staged in shared memory (one record a thread); each pixel walks the round
// front to back with shade() (surfels/surfel_math.h) and stops before its
// transmittance would drop below t_min; the block leaves once all its pixels
// have stopped. Same per-pixel semantics as surfels/cpu/raster_surfels_cpu.cpp.
#include "flat/render/shared/splat_tiles.cuh"
#include "surfels/cuda/surfel_kernels.h"

namespace flat::surfels::cuda {
namespace {

__global__ void __launch_bounds__(kBlockSize)
    raster_forward_kernel(const int2* __restrict__ ranges, const int32_t* __restrict__ values,
                          const PixelSurfel<float>* __restrict__ surfels, const __grid_constant__ ViewChunk chunk,
                          ForwardImages out, unsigned int* __restrict__ max_weight_bits) {
  __shared__ PixelSurfel<float> stage[kBlockSize];
  __shared__ unsigned int wmax[kBlockSize];  // per staged surfel: its largest weight in the tile (float bits)
  const ChunkPixel cp = chunk_pixel(chunk, ranges);
  const ViewParams& vp = chunk.v[cp.view];
  const int tid = threadIdx.x;
  const auto [x, y, inside, px, py] = cp.at;
  const int2 range = cp.range;
  bool done = !inside;
  float T = 1.f, acc[7] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f}, median = 0.f;
  float m_ref = 0.f, m1 = 0.f, m2 = 0.f, dist = 0.f;
  int last = 0;
  for (int base = range.x; base < range.y; base += kBlockSize) {
    if (__syncthreads_count(done) == kBlockSize) break;
    const int count = min(kBlockSize, range.y - base);
    if (tid < count) stage[tid] = surfels[values[base + tid]];
    wmax[tid] = 0u;
    __syncthreads();
    for (int j = 0; !done && j < count; ++j) {
      const PixelSurfel<float>& s = stage[j];
      SurfelFragment<float> f;
      if (!shade(s, px, py, vp.k, f)) continue;
      const float test_T = T * (1.f - f.alpha);
      if (render::stops_before(test_T, vp.k)) {
        done = true;
        break;
      }
      const float w = f.alpha * T;
#pragma unroll
      for (int c = 0; c < 3; ++c) acc[c] += w * s.color[c], acc[4 + c] += w * s.normal[c];
      acc[3] += w * f.z;
      if (T > float(render::kMedianTransmittance)) median = f.z;
      const float m_abs = ndc_depth(f.z);
      if (last == 0) m_ref = m_abs;
      const float m = m_abs - m_ref;
      dist += w * (m * m * (1.f - T) + m2 - 2.f * m * m1);
      m1 += w * m;
      m2 += w * m * m;
      atomicMax(&wmax[j], __float_as_uint(w));  // non-negative floats order as their bits
      T = test_T;
      last = base + j - range.x + 1;
    }
    __syncthreads();
    if (tid < count && wmax[tid] != 0u) atomicMax(&max_weight_bits[stage[tid].index - cp.first], wmax[tid]);
  }
  if (!inside) return;
  // rgb, normal and dist: (views,3,H,W); the others (views,H,W).
  const int64_t HW = cp.hw, p = cp.p, p3 = cp.p3;
#pragma unroll
  for (int c = 0; c < 3; ++c) {
    out.rgb[c * HW + p3] = acc[c] + T * vp.background[c];
    out.normal[c * HW + p3] = acc[4 + c];
  }
  out.alpha[p] = 1.f - T;
  out.depth[p] = acc[3];
  out.median[p] = median;
  out.distortion[p] = dist;
  out.t_final[p] = T;
  out.last[p] = last;
  out.dist[p3] = m_ref;
  out.dist[HW + p3] = m1;
  out.dist[2 * HW + p3] = m2;
}

}  // namespace

void launch_raster_forward(const int2* ranges, const int32_t* values, const PixelSurfel<float>* surfels,
                           const ViewChunk& chunk, const ForwardImages& out, unsigned int* max_weight_bits,
                           cudaStream_t stream) {
  launch_per_chunk_tile(raster_forward_kernel, chunk, stream, ranges, values, surfels, chunk, out, max_weight_bits);
}

}  // namespace flat::surfels::cuda
