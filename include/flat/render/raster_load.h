// How much work a rasterization is, per view: what a speed figure must be
// quoted with, since the rasterizer's time follows these counts far more than
// the triangle count (docs/benchmarks.md, "Triangle rasterizer").
#pragma once
#include <cstdint>
#include <vector>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"
#include "flat/render/rasterize.h"

namespace flat::render {

struct ViewLoad {
  int64_t visible = 0;        // triangles left after culling, with a non-empty support in the image
  int64_t tile_pairs = 0;     // (triangle, tile) pairs binned and sorted (8x8-pixel tiles)
  double list_mean = 0;       // tile list length, mean over tiles
  int64_t list_max = 0;       //   and its maximum
  double entries_mean = 0;    // list entries a pixel's walk passes up to its last blended one,
  int64_t entries_max = 0;    //   mean over pixels, and the maximum
};

// One forward pass (no gradient) of the CUDA rasterizer that also counts the
// load of each view. Throws on the CPU: the counts describe the CUDA tiling.
std::vector<ViewLoad> measure_raster_load(const at::Tensor& vertices, const at::Tensor& colors,
                                          const at::Tensor& opacities, const at::Tensor& sigmas,
                                          const camera::Cameras& cams, int64_t height, int64_t width,
                                          const RasterSettings& settings);

}  // namespace flat::render
