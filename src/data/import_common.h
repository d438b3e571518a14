// Shared steps of the importers (internal): output size, frame writing, the
// camera sanity log line.
#pragma once
#include <cstdint>
#include <string>
#include <utility>

#include <ATen/ATen.h>

#include "flat/data/importers.h"
#include "flat/data/scene.h"

namespace flat::data::detail {

// Image size after limiting the longest side to max_size (0 = unchanged).
std::pair<int64_t, int64_t> import_size(int64_t height, int64_t width, int64_t max_size);

// Resizes rgb (3,H,W) to the scene size and writes images/<stem>.png; returns the relative path.
std::string write_import_image(const Scene& scene, int64_t index, const at::Tensor& rgb);

// Re-orthonormalises the rotation of a c2w (4,4) (float noise in source files).
at::Tensor rigid(const at::Tensor& c2w);

// Logs the principal-axes focus of the imported cameras and writes scene.json.
void finish_import(const Scene& scene);

}  // namespace flat::data::detail
