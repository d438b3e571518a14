// Analytic shapes of the synthetic scenes and their ray casting (internal to
// src/data/synthetic). World frame: y up, floor at y = 0, metres.
#pragma once
#include <array>
#include <cstdint>
#include <vector>

#include <ATen/ATen.h>
#include <glm/vec3.hpp>

namespace flat::data::synth {

// Small fixed-size vector maths on the host is GLM's (the design card's library
// for it); x, y, z also read as [0], [1], [2].
using Vec3 = glm::dvec3;

// An oriented box (rotation `yaw` about world y). `inside` = seen from within
// (the room shell): rays hit its far faces. Surface ids: first_id + 2*axis + (positive side).
struct Box {
  Vec3 centre{}, half{};
  double yaw = 0;
  bool inside = false;
  std::array<Vec3, 6> colour{};  // per face, linear RGB in [0,1]
  double checker = 0.25;         // texture period in metres
  int64_t first_id = 0;
};

struct Sphere {
  Vec3 centre{};
  double radius = 1;
  Vec3 colour{};
  double stripes = 0.2;  // texture period in metres
  int64_t id = 0;
};

struct Layout {
  std::vector<Box> boxes;
  std::vector<Sphere> spheres;
  Vec3 light{0.3, 0.9, 0.2};  // direction towards the light (normalised on use)
  int64_t surface_count = 0;
  // Camera region: for rooms the interior box the camera stays in; the focus
  // point cameras look at or orbit.
  Vec3 focus{}, room_half{};
  double object_radius = 0;  // object family: radius of the object cluster
};

// Closest hits of rays (P,3) against the layout: t (P) (inf = miss), world
// normal (P,3) (outward for solids, inward for the room), surface id (P) (-1),
// albedo (P,3).
struct Hits {
  at::Tensor t, normal, id, albedo;
};
Hits cast_rays(const Layout& layout, const at::Tensor& origins, const at::Tensor& directions);

// Deterministic uniform numbers (same on every platform and standard library).
class Random {
 public:
  explicit Random(uint64_t seed);
  double uniform(double lo = 0, double hi = 1);
  int64_t integer(int64_t lo, int64_t hi);  // inclusive
  Vec3 colour();                            // a saturated pastel colour
 private:
  uint64_t state_;
  uint64_t next();
};

Layout make_room(Random& rng);
Layout make_object_scene(Random& rng);

}  // namespace flat::data::synth
