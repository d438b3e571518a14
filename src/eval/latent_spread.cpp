#include "flat/eval/latent_spread.h"

#include <algorithm>

namespace flat::eval {

LatentSpread latent_spread(const std::vector<at::Tensor>& latents) {
  LatentSpread s;
  if (latents.size() < 2) return s;
  // Per-channel standardisation over the whole set first: a pattern every
  // latent shares by channel (a channel's offset and scale) is not content,
  // and would make any two latents look alike.
  const int64_t C = latents.front().size(0);
  std::vector<at::Tensor> x;
  bool same_channels = true;
  for (const auto& z : latents) {
    same_channels = same_channels && z.dim() >= 1 && z.size(0) == C;
    x.push_back(z.detach().to(at::kCPU, at::kDouble).reshape({z.size(0), -1}));
  }
  if (same_channels) {
    auto all = at::cat(x, 1);
    auto mean = all.mean(1, true), std = all.std(1, false, true).clamp_min(1e-12);
    for (auto& t : x) t = (t - mean) / std;
  }
  std::vector<at::Tensor> centred;
  for (auto& t : x) {
    auto f = t.flatten();
    f = f - f.mean();
    centred.push_back(f / f.norm().clamp_min(1e-12));
  }
  double sum = 0;
  for (size_t i = 0; i < centred.size(); ++i)
    for (size_t j = i + 1; j < centred.size(); ++j) {
      if (!latents[i].sizes().equals(latents[j].sizes())) continue;
      const double r = at::dot(centred[i], centred[j]).item<double>();
      sum += r;
      s.min_correlation = s.pairs == 0 ? r : std::min(s.min_correlation, r);
      s.max_correlation = s.pairs == 0 ? r : std::max(s.max_correlation, r);
      ++s.pairs;
    }
  if (s.pairs > 0) s.mean_correlation = sum / double(s.pairs);
  return s;
}

}  // namespace flat::eval
