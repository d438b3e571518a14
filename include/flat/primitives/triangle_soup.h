// A batch of world-space triangle splats, the output of the triangle builders
// and the input of the rasterizer and exporters.
//
// Layout: batch-first, B scenes of N triangles each, N = T * (H/2) * (W/2),
// triangle n = (t * H/2 + i) * W/2 + j (frame-major, then row, then column of
// the half-resolution token grid). scene(b) gives the (N,3,3) per-scene view
// that the rasterizer and exporters take.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

namespace flat::primitives {

struct TriangleSoup {
  // (B,N,3,3): vertex k of triangle n is vertices[b][n][k] (x,y,z world, metres).
  // Winding: (v1 - v0) x (v2 - v0) points back towards the anchor camera at
  // initialisation (the "front" face is the one the anchor camera sees).
  at::Tensor vertices;
  // (B,N,3) RGB in [0,1], or (B,N,K,3) raw SH coefficients (K = (deg+1)^2).
  at::Tensor colors;
  at::Tensor opacities;  // (B,N) in [0,1]
  at::Tensor sigmas;     // (B,N) window sharpness, > 0

  int64_t batch() const { return vertices.size(0); }
  int64_t size() const { return vertices.size(1); }  // triangles per scene

  // Scene b with the batch dimension dropped: vertices (N,3,3), colors (N,3)
  // or (N,K,3), opacities (N), sigmas (N). Views, no copy.
  TriangleSoup scene(int64_t b) const {
    return TriangleSoup{vertices[b], colors[b], opacities[b], sigmas[b]};
  }
};

}  // namespace flat::primitives
