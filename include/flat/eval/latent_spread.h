// Do the latents carry the scene? A collapsed encoder (a random deep encoder
// with RMS norms and SiLU, say) maps every video to nearly the same pattern,
// and a decoder trained on such latents can only learn the average scene.
// This measures it: the Pearson correlation between the flattened latents of
// different scenes (same shape), after standardising each channel over the
// whole set (a per-channel offset that every latent shares is not content).
// A random-weight Wan encoder gives about 0.99 on our rooms; a trained one
// must stay well below 0.9.
#pragma once
#include <cstdint>
#include <vector>

#include <ATen/ATen.h>

namespace flat::eval {

struct LatentSpread {
  int64_t pairs = 0;  // pairs of latents of the same shape that were compared
  double mean_correlation = NAN, min_correlation = NAN, max_correlation = NAN;
};

// latents: (C, ...) each. Pearson correlation of every pair (i < j) of
// equally shaped latents, after per-channel standardisation over all of them.
LatentSpread latent_spread(const std::vector<at::Tensor>& latents);

}  // namespace flat::eval
