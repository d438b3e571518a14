// A decoded scene in whichever representation the pipeline was configured
// with (pipeline.representation): the paper's triangles, or the 3DGS / 2DGS
// baselines of its Table 1. The one type the pipeline, trainer, evaluation and
// inference pass around, so that they do not branch on the representation
// except where it matters (rasterizer, exporters, mesh).
#pragma once
#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include <ATen/ATen.h>

#include "flat/primitives/gaussian_soup.h"
#include "flat/primitives/triangle_soup.h"

namespace flat::primitives {

// The representations, as named in configs.
inline constexpr const char* kTriangles = "triangles";
inline constexpr const char* kGaussians3d = "3dgs";
inline constexpr const char* kSurfels2d = "2dgs";

struct ScenePrimitives {
  std::string representation = kTriangles;
  TriangleSoup triangles;  // representation "triangles"
  GaussianSoup gaussians;  // representation "3dgs" (3 scales) or "2dgs" (2 scales)

  static ScenePrimitives of(TriangleSoup t) { return {kTriangles, std::move(t), {}}; }
  static ScenePrimitives of(GaussianSoup g);  // "3dgs" or "2dgs" from the number of scales

  bool is_triangles() const { return representation == kTriangles; }
  int64_t batch() const;
  int64_t size() const;              // primitives per scene (batched or one scene)
  at::Tensor opacities() const;      // (B,N) or (N)
  at::Tensor centres() const;        // (B,N,3) or (N,3): triangle centroids, Gaussian means
  ScenePrimitives scene(int64_t b) const;

  // Every tensor, named, in a fixed order ("vertices", "colors", ... or
  // "means", "scales", ...), and the same representation rebuilt from tensors
  // in that order (e.g. detached leaf copies for a split backward).
  std::vector<std::pair<std::string, at::Tensor>> named_tensors() const;
  ScenePrimitives with_tensors(const std::vector<at::Tensor>& tensors) const;
  // Each tensor mapped through f (device moves, dtype casts, index_select).
  ScenePrimitives map(const std::function<at::Tensor(const at::Tensor&)>& f) const;
  // Primitives kept by a (N) int64 index along the primitive dimension (one scene).
  ScenePrimitives index_select(const at::Tensor& keep) const;
};

// Concatenates the scenes' primitives along dimension `dim` (same representation).
ScenePrimitives cat(const std::vector<ScenePrimitives>& parts, int64_t dim);

}  // namespace flat::primitives
