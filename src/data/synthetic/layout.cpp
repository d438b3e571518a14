// Scene layouts of the two synthetic families, drawn from a seeded generator.
#include <cmath>

#include "data/synthetic/shapes.h"

namespace flat::data::synth {

Random::Random(uint64_t seed) : state_(seed * 0x9E3779B97F4A7C15ull + 0x632BE59BD9B4E019ull) {}

// splitmix64: tiny, well mixed and identical on every platform.
uint64_t Random::next() {
  uint64_t z = (state_ += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

double Random::uniform(double lo, double hi) { return lo + (hi - lo) * double(next() >> 11) * 0x1.0p-53; }

int64_t Random::integer(int64_t lo, int64_t hi) { return lo + int64_t(next() % uint64_t(hi - lo + 1)); }

Vec3 Random::colour() {
  // A random hue at moderate saturation: distinct but not garish.
  double h = uniform(0, 6), s = uniform(0.35, 0.75), v = uniform(0.55, 0.95);
  double f = h - std::floor(h), p = v * (1 - s), q = v * (1 - s * f), t = v * (1 - s * (1 - f));
  switch (int(h) % 6) {
    case 0: return {v, t, p};
    case 1: return {q, v, p};
    case 2: return {p, v, t};
    case 3: return {p, q, v};
    case 4: return {t, p, v};
    default: return {v, p, q};
  }
}

namespace {

Box solid(Random& rng, Vec3 centre, Vec3 half, double yaw, int64_t& next_id) {
  Box b;
  b.centre = centre;
  b.half = half;
  b.yaw = yaw;
  Vec3 base = rng.colour();
  for (auto& c : b.colour) {  // faces share a hue with small variations
    double k = rng.uniform(0.8, 1.0);
    c = {base[0] * k, base[1] * k, base[2] * k};
  }
  b.checker = rng.uniform(0.08, 0.3);
  b.first_id = next_id;
  next_id += 6;
  return b;
}

Box shell(Random& rng, Vec3 half, int64_t& next_id) {
  Box room;
  room.centre = {0, half[1], 0};
  room.half = half;
  room.inside = true;
  for (auto& c : room.colour) c = rng.colour();
  room.checker = rng.uniform(0.3, 0.8);
  room.first_id = next_id;
  next_id += 6;
  return room;
}

Sphere ball(Random& rng, Vec3 centre, double radius, int64_t& next_id) {
  Sphere s;
  s.centre = centre;
  s.radius = radius;
  s.colour = rng.colour();
  s.stripes = rng.uniform(0.05, 0.2);
  s.id = next_id++;
  return s;
}

// A layout whose first surfaces are the room shell of half extents `half`
// (floor at y = 0), which both families are drawn inside.
Layout inside_shell(Random& rng, Vec3 half, int64_t& next_id) {
  Layout L;
  L.boxes.push_back(shell(rng, half, next_id));
  L.room_half = half;
  return L;
}

}  // namespace

Layout make_room(Random& rng) {
  int64_t id = 0;
  const Vec3 half{rng.uniform(2.2, 3.5), rng.uniform(1.3, 1.6), rng.uniform(2.2, 3.5)};
  Layout L = inside_shell(rng, half, id);
  L.focus = {0, 1.2, 0};
  // Furniture against the walls: each box touches the floor and one wall.
  int64_t pieces = rng.integer(3, 6);
  for (int64_t i = 0; i < pieces; ++i) {
    int wall = int(rng.integer(0, 3));
    Vec3 h{rng.uniform(0.25, 0.7), rng.uniform(0.2, 0.6), rng.uniform(0.2, 0.4)};
    double along = rng.uniform(-0.6, 0.6);
    Vec3 c{0, h[1], 0};
    double yaw = 0;
    if (wall == 0 || wall == 1) {  // walls at z = +-half_z
      c[0] = along * (half[0] - h[0]);
      c[2] = (wall == 0 ? 1 : -1) * (half[2] - h[2] - 0.02);
    } else {  // walls at x = +-half_x: the box turned by 90 degrees
      yaw = M_PI / 2;
      c[2] = along * (half[2] - h[0]);
      c[0] = (wall == 2 ? 1 : -1) * (half[0] - h[2] - 0.02);
    }
    L.boxes.push_back(solid(rng, c, h, yaw, id));
    if (rng.uniform() < 0.5) {  // something on top
      double r = rng.uniform(0.08, 0.2);
      L.spheres.push_back(ball(rng, {c[0], 2 * h[1] + r, c[2]}, r, id));
    }
  }
  L.light = {rng.uniform(-0.5, 0.5), 1.0, rng.uniform(-0.5, 0.5)};
  L.surface_count = id;
  return L;
}

Layout make_object_scene(Random& rng) {
  int64_t id = 0;
  Layout L = inside_shell(rng, {rng.uniform(6, 9), rng.uniform(3, 4), rng.uniform(6, 9)}, id);
  // A pedestal with a few objects within ~0.8 m of the centre.
  double ph = rng.uniform(0.3, 0.5);
  L.boxes.push_back(solid(rng, {0, ph, 0}, {0.6, ph, 0.6}, rng.uniform(0, M_PI / 2), id));
  int64_t parts = rng.integer(2, 4);
  for (int64_t i = 0; i < parts; ++i) {
    double a = rng.uniform(0, 2 * M_PI), r = rng.uniform(0, 0.3);
    if (rng.uniform() < 0.5) {
      Vec3 h{rng.uniform(0.1, 0.25), rng.uniform(0.1, 0.35), rng.uniform(0.1, 0.25)};
      L.boxes.push_back(solid(rng, {r * std::cos(a), 2 * ph + h[1], r * std::sin(a)}, h, rng.uniform(0, M_PI), id));
    } else {
      double rad = rng.uniform(0.12, 0.3);
      L.spheres.push_back(ball(rng, {r * std::cos(a), 2 * ph + rad, r * std::sin(a)}, rad, id));
    }
  }
  L.focus = {0, 2 * ph + 0.2, 0};
  L.object_radius = 0.9;
  L.light = {rng.uniform(-0.5, 0.5), 1.0, rng.uniform(-0.5, 0.5)};
  L.surface_count = id;
  return L;
}

}  // namespace flat::data::synth
