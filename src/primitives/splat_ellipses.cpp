#include "flat/primitives/splat_ellipses.h"

#include <cmath>

#include "flat/core/small_matmul.h"
#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "primitives/ray_anchors.h"

namespace flat::primitives {

TriangleSoup splat_ellipses(const GaussianSoup& g, int64_t segments) {
  check_shape(g.means, {-1, 3}, "splat_ellipses: means", "(N,3)");
  FLAT_CHECK(segments >= 3, "splat_ellipses: segments must be >= 3, got " + std::to_string(segments));
  const int64_t n = g.means.size(0);
  const auto opts = g.means.options();
  auto q = g.rotations / g.rotations.norm(2, -1, true).clamp_min(1e-12);
  auto R = quaternion_to_matrix(q);  // (N,3,3), columns = the scaled axes
  // The two largest axes (2DGS: its two).
  auto order = at::argsort(g.scales, -1, /*descending=*/true).narrow(1, 0, 2);  // (N,2)
  auto s = g.scales.gather(1, order) * kEllipseSigmas;                          // (N,2)
  auto axes = R.gather(2, order.unsqueeze(1).expand({n, 3, 2})) * s.unsqueeze(1);  // (N,3,2)
  auto angles = at::arange(segments + 1, opts) * (2.0 * M_PI / double(segments));
  auto ring = at::stack({at::cos(angles), at::sin(angles)}, 0);        // (2,S+1)
  auto rim = g.means.unsqueeze(-1) + small_matmul(axes, ring);         // (N,3,S+1)
  auto a = rim.narrow(2, 0, segments), b = rim.narrow(2, 1, segments);  // (N,3,S)
  auto c = g.means.unsqueeze(-1).expand_as(a);
  TriangleSoup t;
  t.vertices = at::stack({c, a, b}, -1).permute({0, 2, 3, 1}).reshape({n * segments, 3, 3}).contiguous();
  t.colors = g.colors.repeat_interleave(segments, 0).contiguous();
  t.opacities = g.opacities.repeat_interleave(segments, 0).contiguous();
  t.sigmas = at::ones({n * segments}, opts);
  return t;
}

}  // namespace flat::primitives
