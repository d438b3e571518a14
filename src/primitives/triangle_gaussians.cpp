#include "flat/primitives/triangle_gaussians.h"

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "primitives/ray_anchors.h"

namespace flat::primitives {

GaussianSoup gaussians_from_triangles(const TriangleSoup& t, int64_t scale_count) {
  check_shape(t.vertices, {-1, 3, 3}, "gaussians_from_triangles: vertices", "(N,3,3)");
  FLAT_CHECK(scale_count == 2 || scale_count == 3,
             "gaussians_from_triangles: scale_count must be 3 (3DGS) or 2 (2DGS)");
  const auto v0 = t.vertices.select(1, 0), v1 = t.vertices.select(1, 1), v2 = t.vertices.select(1, 2);
  const auto a = v1 - v0, b = v2 - v0;
  const auto cross = at::cross(a, b, -1);
  const auto twice_area = cross.norm(2, -1);
  const auto perimeter = a.norm(2, -1) + b.norm(2, -1) + (v2 - v1).norm(2, -1);
  const auto inradius = twice_area / perimeter.clamp_min(1e-30);  // r = area / semi-perimeter
  const auto e1 = a / a.norm(2, -1, true).clamp_min(1e-30);
  const auto n = cross / twice_area.unsqueeze(-1).clamp_min(1e-30);
  const auto e2 = at::cross(n, e1, -1);
  GaussianSoup g;
  g.means = t.vertices.mean(1);
  g.rotations = matrix_to_quaternion(at::stack({e1, e2, n}, -1));  // columns e1, e2, n
  g.scales = scale_count == 3 ? at::stack({inradius, inradius, kThinAxis * inradius}, -1)
                              : at::stack({inradius, inradius}, -1);
  g.colors = t.colors;
  g.opacities = t.opacities;
  return g;
}

}  // namespace flat::primitives
