#include "flat/primitives/head_channels.h"

#include "flat/core/error.h"
#include "flat/primitives/ray_triangles.h"

namespace flat::primitives {

HeadChannels triangle_channels(const std::string& parameterisation, int64_t sh_degree) {
  FLAT_CHECK(sh_degree >= 0 && sh_degree <= 3,
             "triangle_channels: sh_degree must be in [0, 3], got " + std::to_string(sh_degree));
  HeadChannels c;
  if (parameterisation == "three_offsets") {
    c.shape_count = 6;
    c.shape_name = "offsets";
  }
  else if (parameterisation == "global_rotation") c.rotation_count = 4;
  else FLAT_CHECK(parameterisation == "ray_centred",
                  "triangle_channels: unknown parameterisation '" + parameterisation +
                      "' (expected ray_centred, three_offsets or global_rotation)");
  // Fixed order: depth, shape, rotation, colour, opacity, sigma.
  c.depth = 0;
  c.shape = c.depth + 1;
  c.rotation = c.shape + c.shape_count;
  c.colour = c.rotation + c.rotation_count;
  c.colour_count = 3 * sh_coefficient_count(sh_degree);
  c.opacity = c.colour + c.colour_count;
  c.sigma = c.opacity + 1;
  c.total = c.sigma + 1;
  return c;
}

HeadChannels gaussian_channels(int64_t scale_count) {
  FLAT_CHECK(scale_count == 2 || scale_count == 3,
             "gaussian_channels: scale_count must be 3 (3DGS) or 2 (2DGS), got " + std::to_string(scale_count));
  HeadChannels c;
  c.depth = 0;
  c.shape = 1;
  c.shape_count = scale_count;
  c.shape_name = "scale";
  c.rotation = c.shape + scale_count;
  c.rotation_count = 4;
  c.colour = c.rotation + 4;
  c.colour_count = 3;
  c.opacity = c.colour + 3;
  c.sigma = -1;
  c.total = c.opacity + 1;
  return c;
}

void TriangleParamConfig::check() const {
  config::validate_fields(*this, "triangle config");  // the ranges and names declared in visit()
  FLAT_CHECK(depth_far > depth_near, "triangle config: depth_far (" + std::to_string(depth_far) +
                                         ") must exceed depth_near (" + std::to_string(depth_near) + ")");
  FLAT_CHECK(depth_init > depth_near || depth_activation == "sigmoid",
             "triangle config: depth_init must exceed depth_near for the " + depth_activation + " activation");
  FLAT_CHECK(shape_min < 1.0, "triangle config: shape_min must be < 1 (L = I at initialisation)");
  FLAT_CHECK(sigma_init > sigma_min, "triangle config: sigma_init must exceed sigma_min");
  FLAT_CHECK(sh_degree == 0 || colour_activation == "sh",
             "triangle config: sh_degree > 0 needs colour_activation 'sh'");
  (void)triangle_channels(parameterisation, sh_degree);  // checks the names
}

HeadChannels TriangleParamConfig::channels() const {
  return triangle_channels(parameterisation, colour_activation == "sh" ? sh_degree : 0);
}

}  // namespace flat::primitives
