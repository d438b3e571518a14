// Wan VAE: parameter counts of the pretrained architecture (../shared/docs/wan_vae.md),
// streaming == full-sequence for encoder and decoder, frame arithmetic.
#include <functional>
#include <iostream>
#include <vector>

#include "flat/core/error.h"
#include "flat/core/tensor_io.h"
#include "flat/model/wan_vae.h"
#include "flat/model/weights.h"
#include "test_support.h"

using namespace flat::model;

namespace {
WanVAEConfig tiny_config() {
  WanVAEConfig c;
  c.dim = 8;  // widths 8, 16, 32, 32: same structure as dim 96
  return c;
}

// For T' = 1, 2 and 5 latent frames: `run` on `input(t)` streamed equals the
// full-sequence result, which has the shape `shape(t)`.
void check_streaming_equals_full(const std::function<at::Tensor(int64_t)>& input,
                                 const std::function<at::Tensor(const at::Tensor&, bool)>& run,
                                 const std::function<std::vector<int64_t>(int64_t)>& shape) {
  torch::NoGradGuard no_grad;
  for (int64_t t : {1, 2, 5}) {
    auto x = input(t);
    auto full = run(x, /*streaming=*/false);
    auto stream = run(x, /*streaming=*/true);
    REQUIRE(full.sizes() == at::IntArrayRef(shape(t)));
    INFO("T' = " << t);
    CHECK(flat::test::rel_error(stream, full) < 1e-5);
  }
}
}  // namespace

TEST_CASE("Wan VAE parameter counts match the pretrained model", "[model][vae]") {
  torch::NoGradGuard no_grad;
  WanVAE vae(WanVAEConfig{});
  const int64_t decoder = count_parameters(*vae, "decoder.");
  const int64_t decoder_head = count_parameters(*vae, "decoder.head.");
  const int64_t encoder = count_parameters(*vae, "encoder.");
  std::cout << "Wan VAE parameters: decoder " << decoder << " (without RGB head " << decoder - decoder_head
            << "), conv2 " << count_parameters(*vae, "conv2.") << ", encoder " << encoder << ", conv1 "
            << count_parameters(*vae, "conv1.") << ", total " << count_parameters(*vae) << " in "
            << vae->parameters().size() << " tensors\n";
  CHECK(decoder == 73295331);
  CHECK(decoder - decoder_head == 73287456);
  CHECK(count_parameters(*vae, "conv2.") == 272);
  CHECK(encoder == 53595872);
  CHECK(count_parameters(*vae, "conv1.") == 1056);
  CHECK(count_parameters(*vae) == 126892531);
  CHECK(vae->parameters().size() == 194);
  // Per-stage figures of the doc's Decoder3d table.
  CHECK(count_parameters(*vae, "decoder.conv1.") == 166272);
  CHECK(count_parameters(*vae, "decoder.middle.") == 16520064);
  CHECK(count_parameters(*vae, "decoder.upsamples.3.") == 1549248);
  CHECK(count_parameters(*vae, "decoder.upsamples.11.") == 165984);
  CHECK(decoder_head == 7875);
  // A few original key names and shapes.
  auto params = vae->named_parameters();
  CHECK(params["decoder.middle.1.to_qkv.weight"].sizes() == at::IntArrayRef({1152, 384, 1, 1}));
  CHECK(params["decoder.middle.1.norm.gamma"].sizes() == at::IntArrayRef({384, 1, 1}));
  CHECK(params["decoder.upsamples.3.time_conv.weight"].sizes() == at::IntArrayRef({768, 384, 3, 1, 1}));
  CHECK(params["decoder.upsamples.4.shortcut.weight"].sizes() == at::IntArrayRef({384, 192, 1, 1, 1}));
  CHECK(params["encoder.downsamples.5.time_conv.weight"].sizes() == at::IntArrayRef({192, 192, 3, 1, 1}));
  CHECK(params["encoder.head.2.weight"].sizes() == at::IntArrayRef({32, 384, 3, 3, 3}));
}

TEST_CASE("Frame arithmetic: 1+4k frames, clear errors otherwise", "[model][vae]") {
  CHECK(video_frames(13) == 49);
  CHECK(video_frames(21) == 81);
  CHECK(latent_frames(49, "x") == 13);
  REQUIRE_THROWS_WITH(latent_frames(48, "clip.safetensors"), FLAT_CONTAINS("1+4k"));
  WanVAE vae(tiny_config());
  REQUIRE_THROWS_WITH(vae->encode(torch::zeros({1, 3, 6, 16, 16})), FLAT_CONTAINS("got 6"));
}

TEST_CASE("Encoder: streaming equals full sequence (fp32)", "[model][vae]") {
  torch::manual_seed(1);
  WanVAE vae(tiny_config());
  check_streaming_equals_full([](int64_t t) { return torch::rand({1, 3, video_frames(t), 8, 16}) * 2 - 1; },
                              [&](const at::Tensor& video, bool streaming) { return vae->encode(video, streaming); },
                              [](int64_t t) { return std::vector<int64_t>{1, 16, t, 1, 2}; });
}

TEST_CASE("Decoder: streaming equals full sequence (fp32)", "[model][vae]") {
  torch::manual_seed(2);
  WanVAE vae(tiny_config());
  check_streaming_equals_full(
      [](int64_t t) { return torch::randn({1, 16, t, 3, 2}); },
      [&](const at::Tensor& latent, bool streaming) { return vae->decode(latent, streaming, /*clamp=*/false); },
      [](int64_t t) { return std::vector<int64_t>{1, 3, video_frames(t), 24, 16}; });
}

TEST_CASE("Decoder is causal: later latent frames do not change earlier outputs", "[model][vae]") {
  torch::manual_seed(3);
  WanVAE vae(tiny_config());
  torch::NoGradGuard no_grad;
  auto latent = torch::randn({1, 16, 3, 2, 2});
  auto a = vae->decode(latent, false, false);
  auto changed = latent.clone();
  changed.narrow(2, 2, 1).add_(1.0);
  auto b = vae->decode(changed, false, false);
  CHECK(flat::test::rel_error(b.narrow(2, 0, 5), a.narrow(2, 0, 5)) < 1e-6);
  CHECK(flat::test::rel_error(b.narrow(2, 5, 4), a.narrow(2, 5, 4)) > 1e-3);
}

TEST_CASE("Latent normalisation round trip and clamp", "[model][vae]") {
  auto mu = torch::randn({2, 16, 3, 2, 2});
  CHECK(flat::test::rel_error(denormalise_latent(normalise_latent(mu)), mu) < 1e-6);
  auto n = normalise_latent(torch::zeros({1, 16, 1, 1, 1}));
  CHECK(n[0][0][0][0][0].item<double>() == Approx(0.7571 / 2.8184).epsilon(1e-5));
  WanVAE vae(tiny_config());
  torch::NoGradGuard no_grad;
  auto out = vae->decode(torch::randn({1, 16, 2, 2, 2}) * 10);
  CHECK(out.abs().max().item<double>() <= 1.0);
}

TEST_CASE("Sub-pixel upsample conv equals nearest x2 + 3x3 conv", "[model][vae]") {
  torch::manual_seed(4);
  torch::NoGradGuard no_grad;
  for (auto mode : {ResampleMode::upsample2d, ResampleMode::upsample3d}) {
    Resample r(8, mode);
    KernelChoices reference_form;
    reference_form.subpixel_upsample = false;
    Resample ref_r(8, mode, reference_form);
    ref_r->conv_weight.copy_(r->conv_weight);
    ref_r->conv_bias.copy_(r->conv_bias);
    if (r->time_conv) {
      ref_r->time_conv->weight.copy_(r->time_conv->weight);
      ref_r->time_conv->bias.copy_(r->time_conv->bias);
    }
    REQUIRE(r->subpixel_upsample());
    REQUIRE_FALSE(ref_r->subpixel_upsample());
    auto x = torch::randn({2, 8, 3, 5, 4});
    auto ref = ref_r->forward(x);
    auto got = r->forward(x);
    REQUIRE(got.sizes() == ref.sizes());
    CHECK(flat::test::rel_error(got, ref) < 1e-6);
  }
}

// The VAE stage writes its latent statistics into conv1 and conv2 so that the
// file stays a plain Wan VAE: Wan-normalised latents of the folded VAE must
// equal the raw VAE's mu standardised by the statistics, and its decode of
// them the raw VAE's decode of mu.
TEST_CASE("fold_latent_statistics: Wan-normalised latents of the folded VAE are the standardised raw ones",
          "[model][vae]") {
  torch::NoGradGuard no_grad;
  WanVAEConfig c;
  c.dim = 4;
  torch::manual_seed(5);
  WanVAE raw(c);
  raw->eval();
  WanVAE folded(c);
  load_state(*folded, state_tensors(*raw), {}, "raw");
  folded->eval();
  const auto mean = torch::randn({16}, at::kDouble) * 2.0;
  const auto std = torch::rand({16}, at::kDouble) * 3.0 + 0.2;
  folded->fold_latent_statistics(mean, std);
  auto video = torch::rand({1, 3, 5, 16, 24}) * 2 - 1;
  auto mu = raw->encode_moments(video, false).narrow(1, 0, 16);
  auto expected = (mu - mean.to(at::kFloat).view({1, 16, 1, 1, 1})) / std.to(at::kFloat).view({1, 16, 1, 1, 1});
  auto got = folded->encode(video, false);
  CHECK(flat::test::rel_error(got, expected) < 1e-5);
  // Decoding them gives the raw VAE's decode of mu.
  auto raw_video = raw->decoder->forward(raw->conv2->forward(mu));
  auto folded_video = folded->decode(got, false, /*clamp=*/false);
  CHECK(flat::test::rel_error(folded_video, raw_video) < 1e-5);
  // The log-variance moves with the scale: var' = var * (wan_std / std)^2.
  auto lv_raw = raw->encode_moments(video, false).narrow(1, 16, 16);
  auto lv_folded = folded->encode_moments(video, false).narrow(1, 16, 16);
  auto shift = 2.0 * (latent_std(at::kDouble).view({16}) / std).log();
  CHECK(flat::test::rel_error(lv_folded - lv_raw, shift.to(at::kFloat).view({1, 16, 1, 1, 1}).expand_as(lv_raw)) <
        1e-4);
  // Not the identity: without folding the latents differ.
  CHECK(flat::test::rel_error(raw->encode(video, false), expected) > 0.1);
  REQUIRE_THROWS_WITH(folded->fold_latent_statistics(mean, -std), FLAT_CONTAINS("std positive"));
}

TEST_CASE("vae_dim_of_file reads the width from either naming, and names a file that is no VAE", "[model][vae]") {
  const auto dir = flat::test::scratch_dir("vae_dim");
  WanVAEConfig c;
  c.dim = 4;
  WanVAE vae(c);
  save_weights(*vae, (dir / "wan.safetensors").string(), WeightNaming::wan);
  save_weights(*vae, (dir / "diffusers.safetensors").string(), WeightNaming::diffusers);
  CHECK(vae_dim_of_file((dir / "wan.safetensors").string()) == 4);
  CHECK(vae_dim_of_file((dir / "diffusers.safetensors").string()) == 4);
  flat::save_safetensors((dir / "other.safetensors").string(), {{"x", torch::zeros({2})}});
  REQUIRE_THROWS_WITH(vae_dim_of_file((dir / "other.safetensors").string()), FLAT_CONTAINS("other.safetensors"));
}

TEST_CASE("CausalConv3d: one frame through the last temporal tap equals the zero-padded conv, gradients too",
          "[model][vae]") {
  torch::manual_seed(11);
  using flat::model::Int3;
  flat::model::CausalConv3d conv(5, 7, Int3{3, 3, 3}, Int3{1, 1, 1}, Int3{1, 1, 1});
  REQUIRE(conv->has_single_frame_path());
  auto x = torch::randn({2, 5, 1, 6, 4}, torch::requires_grad());
  auto residual = torch::randn({2, 7, 1, 6, 4});
  auto g = torch::randn({2, 7, 1, 6, 4});
  auto fast = conv->forward_single_frame(x, residual);
  auto [gx_fast, gw_fast, gb_fast] = [&] {
    auto grads = torch::autograd::grad({fast}, {x, conv->weight, conv->bias}, {g});
    return std::make_tuple(grads[0], grads[1], grads[2]);
  }();
  auto padded = conv->forward_prepadded(flat::model::pad_past_frames(x, 2), residual);
  auto grads = torch::autograd::grad({padded}, {x, conv->weight, conv->bias}, {g});
  CHECK(fast.sizes() == padded.sizes());
  CHECK(flat::test::rel_error(fast, padded) < 1e-6);
  CHECK(flat::test::rel_error(gx_fast, grads[0]) < 1e-6);
  CHECK(flat::test::rel_error(gw_fast, grads[1]) < 1e-6);
  CHECK(flat::test::rel_error(gb_fast, grads[2]) < 1e-6);
  // The taps that meet the zero frames get no gradient either way.
  CHECK(gw_fast.narrow(2, 0, 2).abs().max().item<double>() == 0.0);
  // forward() takes the single-frame path for one frame; a strided or pastless conv has none.
  CHECK(flat::test::rel_error(conv->forward(x.detach()), conv->forward_prepadded(flat::model::pad_past_frames(x.detach(), 2))) < 1e-6);
  flat::model::CausalConv3d pointwise(5, 7, Int3{1, 1, 1});
  CHECK_FALSE(pointwise->has_single_frame_path());
  REQUIRE_THROWS_WITH(pointwise->forward_single_frame(x), FLAT_CONTAINS("no single-frame path"));
  REQUIRE_THROWS_WITH(conv->forward_single_frame(torch::randn({2, 5, 2, 6, 4})), FLAT_CONTAINS("(B,5,1,H,W)"));
}

TEST_CASE("VAE on one frame (the single-frame path) equals frame 0 of a longer video, output and weight gradients",
          "[model][vae]") {
  // Causal: frame 0's reconstruction depends on frame 0 alone. A single frame
  // takes every conv's single-frame path, the 5-frame video the padded one.
  torch::manual_seed(12);
  WanVAE vae(tiny_config());
  auto video = torch::rand({1, 3, 5, 16, 16}) * 2 - 1;
  auto frame0 = [&](const at::Tensor& v) {
    vae->zero_grad();
    auto out = vae->decode(vae->encode(v, /*streaming=*/false), /*streaming=*/false, /*clamp=*/false).narrow(2, 0, 1);
    (out * out).sum().backward();
    std::vector<at::Tensor> g;
    for (const auto& p : vae->parameters()) g.push_back(p.grad().defined() ? p.grad().clone() : torch::zeros_like(p));
    return std::make_pair(out.detach(), g);
  };
  auto [one, g_one] = frame0(video.narrow(2, 0, 1));
  auto [five, g_five] = frame0(video);
  CHECK(flat::test::rel_error(one, five) < 1e-5);
  REQUIRE(g_one.size() == g_five.size());
  double worst = 0;
  for (size_t i = 0; i < g_one.size(); ++i)
    if (g_five[i].abs().max().item<double>() > 0) worst = std::max(worst, flat::test::rel_error(g_one[i], g_five[i]));
  CHECK(worst < 1e-4);
}
