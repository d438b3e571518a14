// Resizing frames to a training resolution. A pure resize keeps normalised
// intrinsics exactly (pixel centres at +0.5 scale with the image); a centred
// crop to the target aspect ratio shifts and rescales them.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

#include "flat/data/scene_frames.h"

namespace flat::data {

// (K,3,H,W) -> (K,3,h,w): antialiased bilinear when shrinking, bilinear when enlarging.
at::Tensor resize_images(const at::Tensor& images, int64_t height, int64_t width);
// (K,1,H,W) -> (K,1,h,w): nearest (centre-aligned), so depth is never blended across edges.
at::Tensor resize_depth(const at::Tensor& depth, int64_t height, int64_t width);
// (K,3,H,W) -> (K,3,h,w): nearest, re-normalised (zero vectors stay zero).
at::Tensor resize_normals(const at::Tensor& normals, int64_t height, int64_t width);

// The centred crop of an H x W image with the aspect ratio of h x w.
struct Crop {
  int64_t top = 0, left = 0, height = 0, width = 0;
};
Crop aspect_crop(int64_t H, int64_t W, int64_t h, int64_t w);
// Normalised intrinsics (K,4) of an H x W image -> normalised intrinsics of its crop.
at::Tensor crop_intrinsics(const at::Tensor& intrinsics, int64_t H, int64_t W, const Crop& crop);

// Crops every map of `frames` to the aspect ratio of h x w and resizes it;
// returns the intrinsics of the result.
at::Tensor fit_frames(FrameBatch& frames, const at::Tensor& intrinsics, int64_t height, int64_t width);

}  // namespace flat::data
