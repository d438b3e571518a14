// Camera trajectories of the synthetic scenes, after the paper's training
// videos: pans, zooms (dollies) and orbits. OpenCV camera axes, world y up.
#include <algorithm>
#include <cmath>

#include <glm/geometric.hpp>

#include "flat/core/error.h"
#include "data/synthetic/camera_path.h"

namespace flat::data::synth {

namespace {

// Forward direction from yaw (about y, 0 = +z) and pitch (up positive).
Vec3 heading(double yaw, double pitch) {
  return {std::sin(yaw) * std::cos(pitch), std::sin(pitch), std::cos(yaw) * std::cos(pitch)};
}

// OpenCV camera-to-world looking along `forward` with world up +y: camera z =
// forward, x = right = forward x up, y = down = z x x.
std::array<double, 16> look(Vec3 eye, Vec3 forward) {
  const Vec3 z = glm::normalize(forward);
  const Vec3 x = glm::normalize(glm::cross(z, Vec3{0, 1, 0}));
  const Vec3 y = glm::cross(z, x);
  return {x[0], y[0], z[0], eye[0], x[1], y[1], z[1], eye[1], x[2], y[2], z[2], eye[2], 0, 0, 0, 1};
}

double lerp(double a, double b, double t) { return a + (b - a) * t; }

}  // namespace

Path make_path(const Layout& L, bool room, const std::string& motion, int64_t frames, Random& rng) {
  Path p;
  p.motion = motion;
  if (motion == "mixed") {
    const char* kinds[] = {"pan", "zoom", "orbit"};
    p.motion = kinds[rng.integer(0, 2)];
  }
  const double deg = M_PI / 180;
  p.hfov = (room ? rng.uniform(60, 75) : rng.uniform(45, 60)) * deg;
  auto t_of = [&](int64_t i) { return frames > 1 ? double(i) / double(frames - 1) : 0.0; };
  if (room) {
    const Vec3& h = L.room_half;
    // Start in one quadrant of the room, looking across it towards the centre
    // and slightly down, so views show floor, far walls and furniture.
    const double sx = rng.uniform() < 0.5 ? -1 : 1, sz = rng.uniform() < 0.5 ? -1 : 1;
    Vec3 eye{sx * rng.uniform(0.3, 0.5) * h[0], rng.uniform(1.3, 1.7), sz * rng.uniform(0.3, 0.5) * h[2]};
    double yaw = std::atan2(-eye[0], -eye[2]) + rng.uniform(-0.3, 0.3), pitch = rng.uniform(-15, -3) * deg;
    if (p.motion == "pan") {
      double span = rng.uniform(40, 70) * deg * (rng.uniform() < 0.5 ? -1 : 1);
      for (int64_t i = 0; i < frames; ++i) p.c2w.push_back(look(eye, heading(yaw + span * t_of(i), pitch)));
    } else if (p.motion == "zoom") {
      Vec3 f = heading(yaw, pitch);
      double dist = rng.uniform(0.6, 1.2);
      for (int64_t i = 0; i < frames; ++i) {
        Vec3 e = eye + f * (dist * t_of(i));
        // Stay well inside the room (furniture stands along the walls).
        e[0] = std::clamp(e[0], -(h[0] - 1.0), h[0] - 1.0);
        e[2] = std::clamp(e[2], -(h[2] - 1.0), h[2] - 1.0);
        p.c2w.push_back(look(e, f));
      }
    } else if (p.motion == "orbit") {
      // Arc around a piece of furniture, starting near the room centre.
      const Box& target = L.boxes[size_t(rng.integer(1, int64_t(L.boxes.size()) - 1))];
      Vec3 c = target.centre;
      double radius = std::hypot(eye[0] - c[0], eye[2] - c[2]);
      double a0 = std::atan2(eye[0] - c[0], eye[2] - c[2]), sweep = rng.uniform(15, 25) * deg;
      for (int64_t i = 0; i < frames; ++i) {
        double a = a0 + sweep * (2 * t_of(i) - 1);
        Vec3 e{c[0] + radius * std::sin(a), eye[1], c[2] + radius * std::cos(a)};
        p.c2w.push_back(look(e, c - e));
      }
    } else {
      fail("synthetic scene: unknown motion '" + motion + "' (pan, zoom, orbit, mixed)");
    }
    return p;
  }
  // Object-centric: the camera looks at the object cluster from 2.2-3.5 m.
  const Vec3& c = L.focus;
  double radius = rng.uniform(2.2, 3.5), elev = rng.uniform(12, 35) * deg, a0 = rng.uniform(0, 2 * M_PI);
  auto on_circle = [&](double a, double r) {
    return Vec3{c[0] + r * std::cos(elev) * std::sin(a), c[1] + r * std::sin(elev), c[2] + r * std::cos(elev) * std::cos(a)};
  };
  if (p.motion == "orbit") {
    double sweep = rng.uniform(120, 300) * deg * (rng.uniform() < 0.5 ? -1 : 1);
    for (int64_t i = 0; i < frames; ++i) {
      Vec3 e = on_circle(a0 + sweep * t_of(i), radius);
      p.c2w.push_back(look(e, c - e));
    }
  } else if (p.motion == "pan") {
    Vec3 e = on_circle(a0, radius);
    Vec3 f = glm::normalize(c - e);
    double yaw0 = std::atan2(f[0], f[2]), pitch = std::asin(f[1]), span = rng.uniform(15, 25) * deg;
    for (int64_t i = 0; i < frames; ++i) p.c2w.push_back(look(e, heading(yaw0 + span * (2 * t_of(i) - 1), pitch)));
  } else if (p.motion == "zoom") {
    double end = rng.uniform(0.5, 0.7);
    for (int64_t i = 0; i < frames; ++i) {
      Vec3 e = on_circle(a0, radius * lerp(1.0, end, t_of(i)));
      p.c2w.push_back(look(e, c - e));
    }
  } else {
    fail("synthetic scene: unknown motion '" + motion + "' (pan, zoom, orbit, mixed)");
  }
  return p;
}

}  // namespace flat::data::synth
