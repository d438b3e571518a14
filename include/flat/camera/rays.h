// Per-pixel rays: d = normalize(R_c2w ((u+0.5-cx)/fx, (v+0.5-cy)/fy, 1)),
// o = camera centre. At half resolution with the same normalised intrinsics
// the rays pass exactly through the centres of the 2x2 pixel blocks of the
// full-resolution image, which is how FLAT's anchor rays are made.
#pragma once
#include <ATen/ATen.h>

#include "flat/camera/cameras.h"

namespace flat::camera {

struct Rays {
  at::Tensor origins;     // (V,H,W,3)
  at::Tensor directions;  // (V,H,W,3), unit length
};

Rays pixel_rays(const Cameras& cameras, int64_t height, int64_t width);

}  // namespace flat::camera
