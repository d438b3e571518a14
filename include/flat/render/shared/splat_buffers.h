// The tensor bundles between the 3DGS and 2DGS rasterizers' autograd Function
// (splat_function.h) and their CPU / CUDA back ends (gaussians/, surfels/):
// both take the same five inputs and give render::RenderOutput images
// (empty_images(), raster_dispatch.h). Public, under flat/render/shared/,
// because gaussians and surfels include it; not part of the rasterizer's API.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

#include "flat/render/shared/compositing.h"
#include "flat/render/shared/splat_tiles.h"

namespace flat::render {

// Contiguous tensors on one device, one dtype (float; double on the CPU):
// means (N,3), scales (N,3) (3DGS) or (N,2) (2DGS), rotations (N,4), colors
// (N,3), opacities (N); on the host in that dtype: w2c (V,4,4), K (V,4)
// pixel intrinsics fx, fy, cx, cy, background (3).
struct SplatInputs {
  at::Tensor means, scales, rotations, colors, opacities;
  at::Tensor w2c, K, background;
  int64_t height = 0, width = 0;
  CompositingConstants k;
  // The value checks' statistics (input_stats(), raster_dispatch.h) on the
  // host; for CUDA inputs filled by an asynchronous copy: read only once the
  // stream that computed them has been waited for. Empty: nothing left to
  // check (no splats, or the rasterizer checked them before the call).
  at::Tensor value_stats;
};

// Fails unless in.value_stats (empty: nothing to check) say the inputs are
// finite, opacities lie in [0, 1], scales are positive and rotations are
// non-zero quaternions; `fn` names the rasterizer (splat_function.cpp).
void check_splat_values(const SplatInputs& in, const char* fn);

// View `view` of `in` as the CUDA kernels read it (in.w2c, in.K and
// in.background in float, on the host).
inline splat::ViewParams splat_view(const SplatInputs& in, int64_t view) {
  return make_tile_view(in.w2c.data_ptr<float>() + 16 * view, in.K.data_ptr<float>() + 4 * view, in.k, in.width,
                        in.height, splat::kTileSize, in.background.data_ptr<float>());
}

// Views [first, first + count) of `in` as one launch's chunk (count <=
// splat::kMaxChunkViews).
inline splat::ViewChunk view_chunk(const SplatInputs& in, int64_t first, int count) {
  splat::ViewChunk c;
  c.views = count;
  c.per_view = in.means.size(0);
  for (int v = 0; v < count; ++v) c.v[v] = splat_view(in, first + v);
  return c;
}

// Upstream gradients, (V,C,H,W) each, defined (zeros where the output had
// none); normal and distortion only where the rasterizer has those outputs.
struct SplatOutputGrads {
  at::Tensor rgb, alpha, depth, normal, distortion;
};

struct SplatGrads {
  at::Tensor means, scales, rotations, colors, opacities;  // shapes of the inputs

  // Zeros: both back ends add each view's share into them.
  static SplatGrads zeros_for(const SplatInputs& in) {
    return {at::zeros_like(in.means), at::zeros_like(in.scales), at::zeros_like(in.rotations),
            at::zeros_like(in.colors), at::zeros_like(in.opacities)};
  }
};

}  // namespace flat::render
