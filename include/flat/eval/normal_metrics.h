// Normal accuracy (paper, Table "Novel View Synthesis and Geometry Quality":
// Geometry Quality L1 and Cosine) between rendered and reference normals.
#pragma once
#include <ATen/ATen.h>

namespace flat::eval {

struct NormalAccuracy {
  double mean_cosine = 0;  // mean over valid pixels of n . N (both made unit length)
  double mean_l1 = 0;      // mean over valid pixels and the 3 components of |n - N|
  int64_t valid_pixels = 0;
};

// rendered, reference: (V,3,H,W) camera-space normals; mask: (V,1,H,W) bool,
// undefined = all. Pixels where either normal has length < 1e-6 are not valid.
// With no valid pixel, both means are NaN and valid_pixels is 0.
NormalAccuracy normal_accuracy(const at::Tensor& rendered, const at::Tensor& reference, const at::Tensor& mask = {});

}  // namespace flat::eval
