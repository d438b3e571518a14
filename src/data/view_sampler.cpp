#include "flat/data/view_sampler.h"

#include <algorithm>

#include "flat/core/error.h"

namespace flat::data {

namespace {

int64_t uniform(std::mt19937_64& rng, int64_t n) { return int64_t(rng() % uint64_t(n)); }  // [0, n)

// k distinct elements of `pool` (partial Fisher-Yates), sorted.
std::vector<int64_t> choose(std::vector<int64_t> pool, int64_t k, std::mt19937_64& rng) {
  k = std::min<int64_t>(k, int64_t(pool.size()));
  for (int64_t i = 0; i < k; ++i) std::swap(pool[size_t(i)], pool[size_t(i + uniform(rng, int64_t(pool.size()) - i))]);
  pool.resize(size_t(k));
  std::sort(pool.begin(), pool.end());
  return pool;
}

}  // namespace

int64_t window_span(const ViewSamplerConfig& c) { return 1 + (c.input_frames - 1) * c.frame_stride; }

ViewSample sample_views(int64_t n, const ViewSamplerConfig& c, std::mt19937_64& rng,
                        const std::vector<LatentWindow>* latent_windows) {
  FLAT_CHECK(c.input_frames >= 1 && c.target_views >= 1 && c.frame_stride >= 1,
             "view sampler: input_frames, target_views and frame_stride must be positive");
  FLAT_CHECK(c.unseen_fraction >= 0 && c.unseen_fraction <= 1, "view sampler: unseen_fraction must be in [0, 1]");
  ViewSample s;
  if (latent_windows) {
    std::vector<int64_t> match;
    for (size_t i = 0; i < latent_windows->size(); ++i)
      if ((*latent_windows)[i].count == c.input_frames) match.push_back(int64_t(i));
    FLAT_CHECK(!match.empty(), "no latent window of " + std::to_string(c.input_frames) + " frames");
    s.latent_window = match[size_t(uniform(rng, int64_t(match.size())))];
    const auto& w = (*latent_windows)[size_t(s.latent_window)];
    for (int64_t i = 0; i < w.count; ++i) s.input.push_back(w.start + i);  // latents cover consecutive frames
  } else {
    const int64_t span = window_span(c);
    FLAT_CHECK(n >= span, "scene has " + std::to_string(n) + " frames, a window needs " + std::to_string(span));
    const int64_t start = uniform(rng, n - span + 1);
    for (int64_t i = 0; i < c.input_frames; ++i) s.input.push_back(start + i * c.frame_stride);
  }
  const int64_t lo = s.input.front(), hi = s.input.back();
  std::vector<int64_t> outside;
  for (int64_t f = 0; f < n; ++f) {
    if (f >= lo && f <= hi) continue;  // frames between window frames count as inside (seen region)
    const int64_t gap = f < lo ? lo - f : f - hi;
    if (c.unseen_max_gap <= 0 || gap <= c.unseen_max_gap) outside.push_back(f);
  }
  const int64_t want_unseen = int64_t(double(c.target_views) * c.unseen_fraction);
  auto unseen = choose(outside, want_unseen, rng);
  const int64_t want_seen = c.target_views - int64_t(unseen.size());
  std::vector<int64_t> seen = choose(s.input, want_seen, rng);
  // More seen targets than window frames (V > F): repeat window frames.
  while (int64_t(seen.size()) < want_seen) seen.push_back(s.input[size_t(uniform(rng, int64_t(s.input.size())))]);
  std::sort(seen.begin(), seen.end());
  for (int64_t f : seen) {
    s.targets.push_back(f);
    s.seen.push_back(true);
  }
  for (int64_t f : unseen) {
    s.targets.push_back(f);
    s.seen.push_back(false);
  }
  return s;
}

}  // namespace flat::data
