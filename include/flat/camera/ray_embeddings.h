// Dense ray embeddings used for camera conditioning (paper, Camera Conditioning).
//   Plucker: (o x d, d)
//   RPPC   : (o - (o.d) d, d)   the point on the ray closest to the world origin, then d
// Both return (V,6,H,W) with the 3-channel halves in that order.
// The chain of the paper's Camera Conditioning, one step per file: this RPPC map
// -> its VAE encoding E_ref, E_dir (model/camera_latents.h) -> the fusion with
// the video latent (model/camera_adapter.h).
#pragma once
#include <ATen/ATen.h>

#include "flat/camera/rays.h"

namespace flat::camera {

at::Tensor plucker_map(const Rays& rays);
at::Tensor rppc_map(const Rays& rays);

}  // namespace flat::camera
