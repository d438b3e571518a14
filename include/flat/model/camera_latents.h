// Camera latents (paper: Camera Conditioning, following Lyra): the RPPC ray maps
// of the F frames, each 3-channel half (reference point, direction) encoded
// separately by the frozen VAE encoder (normalised mu), concatenated ref then
// dir: (1, 32, T', H/8, W/8). They depend only on the trajectory, so they can
// be computed once and cached (save_camera_latents / load_camera_latents).
// Before: the RPPC map (camera/ray_embeddings.h); after: the fusion layer
// (model/camera_adapter.h).
#pragma once
#include <cstdint>
#include <string>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"
#include "flat/model/wan_vae.h"

namespace flat::model {

// The ray map as two videos (1,3,F,H,W): rays "rppc" (reference point,
// direction: the paper) or "plucker" (moment o x d, direction: the
// conditioning ablation).
std::pair<at::Tensor, at::Tensor> ray_videos(const flat::camera::Cameras& cams, int64_t height, int64_t width,
                                             const std::string& rays = "rppc");

// Runs without autograd, on the VAE's device and dtype. F = cams.size() must be
// 1+4k; height and width are the video's (multiples of 8).
at::Tensor encode_camera_latents(WanVAE& vae, const flat::camera::Cameras& cams, int64_t height, int64_t width,
                                 bool streaming = true, const std::string& rays = "rppc");

// Cache files: tensor "camera_latents" plus metadata (frames, height, width).
void save_camera_latents(const std::string& path, const at::Tensor& latents, int64_t height, int64_t width);
at::Tensor load_camera_latents(const std::string& path);

}  // namespace flat::model
