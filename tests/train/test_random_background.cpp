// loss.random_background: the uncovered share of a training render takes the
// drawn colour, the covered share keeps the render, and the draw follows the
// seed alone (exact resume).
#include "flat/train/random_background.h"
#include "test_support.h"

using flat::pipeline::RenderedViews;
using flat::train::use_random_background;

namespace {

// Two views of 2x3 pixels: opaque, empty and half-covered pixels.
RenderedViews views_with(const std::vector<double>& background) {
  RenderedViews v;
  auto gen = at::make_generator<at::CPUGeneratorImpl>(3);
  auto alpha = at::tensor({1.0f, 0.0f, 0.5f, 1.0f, 0.0f, 0.25f}).view({1, 1, 2, 3}).repeat({2, 1, 1, 1});
  // What a compositor gives: covered colour + (1 - alpha) * background.
  auto covered = at::rand({2, 3, 2, 3}, gen) * alpha;
  auto bg = at::tensor(std::vector<float>(background.begin(), background.end())).view({1, 3, 1, 1});
  v.alpha = alpha;
  v.rgb = covered + (1 - alpha) * bg;
  return v;
}

}  // namespace

TEST_CASE("random background: empty pixels take the drawn colour, opaque ones keep the render", "[train]") {
  for (const std::vector<double>& configured : {std::vector<double>{0, 0, 0}, std::vector<double>{0.2, 0.9, 0.4}}) {
    auto v = views_with(configured);
    const auto before = v.rgb.clone();
    const auto colours = use_random_background(v, configured, 77);
    REQUIRE(colours.sizes() == at::IntArrayRef({2, 3}));
    for (int64_t view = 0; view < 2; ++view) {
      INFO("view " << view);
      const auto c = colours[view].view({3});
      // Opaque pixel (0,0) and (1,0): unchanged.
      CHECK(at::allclose(v.rgb[view].select(1, 0).select(1, 0), before[view].select(1, 0).select(1, 0)));
      // Empty pixel (0,1): exactly the colour.
      CHECK(at::allclose(v.rgb[view].select(1, 0).select(1, 1), c, 1e-6, 1e-6));
      // Half-covered pixel (0,2): the covered half plus half the colour.
      const auto covered = before[view].select(1, 0).select(1, 2) - 0.5 * at::tensor(std::vector<float>(
                                                                            configured.begin(), configured.end()));
      CHECK(at::allclose(v.rgb[view].select(1, 0).select(1, 2), covered + 0.5 * c, 1e-6, 1e-6));
    }
    // One colour per view, not the configured one.
    CHECK_FALSE(at::allclose(colours[0], colours[1]));
  }
}

TEST_CASE("random background: the seed alone decides the colours; gradients reach alpha", "[train]") {
  auto a = views_with({0, 0, 0}), b = views_with({0, 0, 0}), c = views_with({0, 0, 0});
  const auto ca = use_random_background(a, {0, 0, 0}, 5);
  const auto cb = use_random_background(b, {0, 0, 0}, 5);
  const auto cc = use_random_background(c, {0, 0, 0}, 6);
  CHECK(at::equal(ca, cb));
  CHECK(at::equal(a.rgb, b.rgb));
  CHECK_FALSE(at::allclose(ca, cc));
  // d rgb / d alpha = -(colour - configured) per channel: an empty pixel is
  // pushed to cover itself when the colour is wrong, whatever the background was.
  auto v = views_with({0, 0, 0});
  v.alpha.requires_grad_(true);
  const auto colours = use_random_background(v, {0, 0, 0}, 9);
  v.rgb.sum().backward();
  const auto expected = -colours.sum(1).view({2, 1, 1, 1}).expand({2, 1, 2, 3});
  CHECK(at::allclose(v.alpha.grad(), expected, 1e-6, 1e-6));
  REQUIRE_THROWS_WITH(use_random_background(v, {0, 0}, 1), FLAT_CONTAINS("3 values"));
}
