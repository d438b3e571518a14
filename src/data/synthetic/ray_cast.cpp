// Vectorised ray casting of boxes and spheres with ATen (fast on a few CPU
// cores): each shape gives a hit distance per ray and the closest one wins.
#include <cmath>
#include <limits>

#include "data/synthetic/shapes.h"

namespace flat::data::synth {

namespace {

constexpr double kEps = 1e-6;
const double kInf = std::numeric_limits<double>::infinity();

at::Tensor vec(const Vec3& v, const at::Tensor& like) {
  return at::tensor({v[0], v[1], v[2]}, like.options().dtype(at::kDouble)).to(like.scalar_type());
}

// Texture: a 3D checker in the shape's local frame, modulated by a soft
// second frequency so that neighbouring squares are distinguishable.
at::Tensor checker(const at::Tensor& local, double period) {
  auto cells = at::floor(local / period).sum(-1);
  auto parity = cells - 2.0 * at::floor(cells / 2.0);  // 0 or 1
  auto wave = at::sin(local.select(-1, 0) * (2.3 / period) + local.select(-1, 2) * (1.7 / period));
  return (0.72 + 0.28 * parity + 0.06 * wave).unsqueeze(-1);
}

struct Candidate {
  at::Tensor t, normal, id, albedo;
};

Candidate cast_box(const Box& b, const at::Tensor& o, const at::Tensor& d) {
  const double c = std::cos(b.yaw), s = std::sin(b.yaw);
  // Rotation about y: local -> world columns.
  auto R = at::tensor({c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c}, o.options().dtype(at::kDouble)).view({3, 3}).to(o.scalar_type());
  auto lo = at::matmul(o - vec(b.centre, o), R);  // R^T (o - c) for row vectors
  auto ld = at::matmul(d, R);
  // Avoid 0-division: a zero component gets a tiny value of positive sign.
  ld = at::where(ld.abs() < 1e-12, at::full_like(ld, 1e-12), ld);
  auto half = vec(b.half, o);
  auto t1 = (-half - lo) / ld, t2 = (half - lo) / ld;
  auto near = at::minimum(t1, t2), far = at::maximum(t1, t2);
  auto [tmin, amin] = near.max(-1);
  auto [tmax, amax] = far.min(-1);
  auto hit = tmin <= tmax;
  at::Tensor t, axis;
  if (b.inside) {
    t = at::where(hit & (tmax > kEps), tmax, at::full_like(tmax, kInf));
    axis = amax;
  } else {
    t = at::where(hit & (tmin > kEps), tmin, at::full_like(tmin, kInf));
    axis = amin;
  }
  // Normal on the hit axis, against the ray (outward on the entry face, inward on the exit face).
  auto onehot = at::one_hot(axis, 3).to(o.scalar_type());
  auto dsign = at::sign((ld * onehot).sum(-1, true));
  auto local_n = -dsign * onehot;
  auto normal = at::matmul(local_n, R.t());
  // Entry through the + face has d < 0; exit through it (room) has d > 0.
  auto positive = b.inside ? (dsign > 0) : (dsign < 0);
  auto face = axis * 2 + positive.squeeze(-1).to(at::kLong);
  auto id = face + b.first_id;
  std::vector<double> cols;
  for (const auto& col : b.colour) cols.insert(cols.end(), {col.x, col.y, col.z});
  auto palette = at::tensor(cols, o.options().dtype(at::kDouble)).view({6, 3}).to(o.scalar_type());
  auto local_hit = lo + at::where(at::isinf(t), at::zeros_like(t), t).unsqueeze(-1) * ld;
  auto albedo = palette.index_select(0, face) * checker(local_hit, b.checker);
  return {t, normal, id, albedo};
}

Candidate cast_sphere(const Sphere& sp, const at::Tensor& o, const at::Tensor& d) {
  auto oc = o - vec(sp.centre, o);
  auto b = (oc * d).sum(-1);
  auto c = (oc * oc).sum(-1) - sp.radius * sp.radius;
  auto disc = b * b - c;
  auto root = at::sqrt(at::clamp_min(disc, 0));
  auto t0 = -b - root, t1 = -b + root;
  auto t = at::where(t0 > kEps, t0, t1);
  t = at::where((disc >= 0) & (t > kEps), t, at::full_like(t, kInf));
  auto local = oc + at::where(at::isinf(t), at::zeros_like(t), t).unsqueeze(-1) * d;
  auto normal = local / sp.radius;
  auto id = at::full_like(t, double(sp.id)).to(at::kLong);
  // Latitude stripes plus a longitude checker on the sphere surface.
  auto lat = at::asin(at::clamp(normal.select(-1, 1), -1, 1)) * sp.radius;
  auto lon = at::atan2(normal.select(-1, 2), normal.select(-1, 0)) * sp.radius;
  auto uv = at::stack({lat, lon, at::zeros_like(lat)}, -1);
  auto albedo = vec(sp.colour, o) * checker(uv, sp.stripes);
  return {t, normal, id, albedo};
}

void keep_closer(Hits& best, const Candidate& c) {
  auto closer = c.t < best.t;
  best.t = at::where(closer, c.t, best.t);
  auto m = closer.unsqueeze(-1);
  best.normal = at::where(m, c.normal, best.normal);
  best.albedo = at::where(m, c.albedo, best.albedo);
  best.id = at::where(closer, c.id, best.id);
}

}  // namespace

Hits cast_rays(const Layout& layout, const at::Tensor& origins, const at::Tensor& directions) {
  Hits best;
  best.t = at::full({origins.size(0)}, kInf, origins.options());
  best.normal = at::zeros_like(origins);
  best.albedo = at::zeros_like(origins);
  best.id = at::full({origins.size(0)}, -1, origins.options().dtype(at::kLong));
  for (const auto& b : layout.boxes) keep_closer(best, cast_box(b, origins, directions));
  for (const auto& s : layout.spheres) keep_closer(best, cast_sphere(s, origins, directions));
  return best;
}

}  // namespace flat::data::synth
