// FLAT scene decoder: shapes and channel map, zero-initialised camera adapter,
// gradients reaching the adapter, streaming == full, camera latents.
#include <algorithm>
#include <iostream>

#include "flat/camera/cameras.h"
#include "flat/core/config.h"
#include "flat/core/error.h"
#include "flat/model/camera_latents.h"
#include "flat/model/scene_decoder.h"
#include "flat/model/wan_vae.h"
#include "flat/model/weights.h"
#include "test_support.h"

using namespace flat::model;

namespace {
SceneDecoderConfig tiny_config(const std::string& heads = "independent") {
  SceneDecoderConfig c;
  c.vae.dim = 8;
  c.heads = heads;
  return c;
}

flat::camera::Cameras orbit(int64_t n) {
  flat::camera::Cameras cams;
  cams.intrinsics = torch::tensor({0.8f, 1.2f, 0.5f, 0.5f}).repeat({n, 1});
  cams.c2w = torch::eye(4).repeat({n, 1, 1});
  for (int64_t i = 0; i < n; ++i) {
    cams.c2w[i][0][3] = 0.1f * float(i);
    cams.c2w[i][2][3] = -1.0f;
  }
  return cams;
}
}  // namespace

TEST_CASE("Scene decoder parameter count at the paper's size", "[model][scene]") {
  torch::NoGradGuard no_grad;
  SceneDecoder scene(SceneDecoderConfig{});
  const int64_t total = count_parameters(*scene);
  std::cout << "Scene decoder parameters (independent heads): total " << total << " = adapter "
            << count_parameters(*scene, "adapter.") << " + conv2 " << count_parameters(*scene, "conv2.")
            << " + decoder " << count_parameters(*scene, "decoder.") << " + heads " << count_parameters(*scene, "heads.")
            << "\n";
  CHECK(count_parameters(*scene, "decoder.") == 73287456);  // the Wan decoder without its RGB head
  CHECK(count_parameters(*scene, "adapter.") == (32 * 16 * 27 + 16) + (16 * 16 * 27 + 16));
  // Independent heads: 6 x (gamma 96) + 96*27*12 weights + 12 biases.
  CHECK(count_parameters(*scene, "heads.") == 6 * 96 + 96 * 27 * 12 + 12);
  SceneDecoderConfig mono;
  mono.heads = "monolithic";
  SceneDecoder scene_mono(mono);
  std::cout << "Scene decoder parameters (monolithic head): total " << count_parameters(*scene_mono) << "\n";
  CHECK(count_parameters(*scene_mono, "heads.") == 96 + 96 * 27 * 12 + 12);
}

TEST_CASE("Heads follow the triangle channel layout, ablations and SH included", "[model][scene]") {
  using flat::primitives::triangle_channels;
  const auto groups = head_groups(triangle_channels("ray_centred"));
  REQUIRE(groups.size() == 6);
  const std::vector<std::tuple<std::string, int64_t, int64_t>> expected = {
      {"depth", 0, 1}, {"cholesky", 1, 3}, {"rotation", 4, 3}, {"colour", 7, 3}, {"opacity", 10, 1}, {"sigma", 11, 1}};
  for (size_t i = 0; i < groups.size(); ++i) {
    INFO(groups[i].first);
    CHECK(groups[i].first == std::get<0>(expected[i]));
    CHECK(groups[i].second.start == std::get<1>(expected[i]));
    CHECK(groups[i].second.count == std::get<2>(expected[i]));
  }
  CHECK(head_groups(triangle_channels("three_offsets"))[1].first == "offsets");
  // Every layout: the decoder emits exactly its channels, independent and monolithic.
  struct Case {
    std::string param;
    int64_t sh_degree, total;
  };
  for (const Case& c : {Case{"ray_centred", 0, 12}, Case{"three_offsets", 0, 15}, Case{"global_rotation", 0, 13},
                        Case{"ray_centred", 1, 21}}) {
    for (const std::string mode : {"independent", "monolithic"}) {
      INFO(c.param << " sh " << c.sh_degree << " " << mode);
      torch::NoGradGuard no_grad;
      SceneDecoder scene(tiny_config(mode), triangle_channels(c.param, c.sh_degree));
      CHECK(scene->channels().total == c.total);
      const auto out = scene->forward(torch::randn({1, 16, 2, 2, 3}), torch::randn({1, 32, 2, 2, 3}));
      CHECK(out.size(1) == c.total);
    }
  }
}

TEST_CASE("Scene decoder shapes, both head modes, streaming == full", "[model][scene]") {
  for (const std::string mode : {"independent", "monolithic"}) {
    torch::manual_seed(7);
    SceneDecoder scene(tiny_config(mode));
    torch::NoGradGuard no_grad;
    auto latent = torch::randn({1, 16, 3, 2, 3});
    auto cams = torch::randn({1, 32, 3, 2, 3});
    auto full = scene->forward(latent, cams, /*streaming=*/false);
    REQUIRE(full.sizes() == at::IntArrayRef({1, 12, 9, 8, 12}));  // T = 1+4(3-1), (4h, 4w) = (H/2, W/2)
    // Streaming, with the low-resolution trunk taking 1, 2 or all latent frames per step.
    for (const int64_t trunk_frames : {1, 2, 8}) {
      SceneDecoderConfig cfg = tiny_config(mode);
      cfg.stream_trunk_frames = trunk_frames;
      torch::manual_seed(7);
      SceneDecoder same(cfg);
      auto stream = same->forward(latent, cams, /*streaming=*/true);
      INFO(mode << ", trunk frames per step " << trunk_frames);
      CHECK(flat::test::rel_error(stream, full) < 1e-5);
    }
    CHECK(scene->features(latent, cams).size(1) == 8);
  }
  SceneDecoder scene(tiny_config());
  REQUIRE_THROWS_WITH(scene->forward(torch::randn({1, 16, 3, 2, 3}), torch::randn({1, 32, 2, 2, 3})),
                      FLAT_CONTAINS("do not match the latent"));
}

TEST_CASE("Zero-initialised adapter: cameras change nothing at init, gradient reaches its last layer",
          "[model][scene]") {
  torch::manual_seed(8);
  SceneDecoder scene(tiny_config());
  auto latent = torch::randn({1, 16, 2, 2, 2});
  auto cams = torch::randn({1, 32, 2, 2, 2});
  {
    torch::NoGradGuard no_grad;
    CHECK(torch::equal(scene->forward(latent, cams), scene->forward(latent)));
  }
  auto out = scene->forward(latent, cams);
  (out * torch::randn_like(out)).sum().backward();
  auto g = scene->adapter->zero_conv->weight.grad();
  REQUIRE(g.defined());
  CHECK(g.abs().sum().item<double>() > 0.0);
  CHECK(scene->adapter->zero_conv->bias.grad().abs().sum().item<double>() > 0.0);
}

TEST_CASE("Kernel choices: YAML keys reach every module; the reference upsample form gives the same output",
          "[model][scene]") {
  const KernelChoices defaults;
  CHECK(defaults.fused_norm);
  CHECK(defaults.subpixel_upsample);
  CHECK(defaults.conv_backend == "auto");
  const auto cfg = flat::config::parse<SceneDecoderConfig>(
      "vae: {dim: 8}\nkernels: {fused_norm: false, subpixel_upsample: false, conv_backend: cudnn}\n", "model.yaml");
  REQUIRE_FALSE(cfg.kernels.fused_norm);
  REQUIRE_FALSE(cfg.kernels.subpixel_upsample);
  REQUIRE(cfg.kernels.conv_backend == "cudnn");
  CHECK(flat::config::to_yaml(cfg).find("conv_backend: cudnn") != std::string::npos);

  torch::manual_seed(7);
  SceneDecoder fast(tiny_config());  // the defaults: sub-pixel upsampling
  torch::manual_seed(7);
  SceneDecoder reference(cfg);  // same architecture and seed: same weights
  // Every norm, conv and upsample of the model holds the choices it was built with.
  auto kernels_of = [](torch::nn::Module& model, int64_t expected_upsamples) {
    std::vector<std::string> seen;
    int64_t upsamples = 0;
    for (const auto& m : model.modules(/*include_self=*/false)) {
      if (const auto* n = m->as<RMSNormImpl>()) seen.push_back(n->fused() ? "fused" : "aten");
      if (const auto* c = m->as<CausalConv3dImpl>()) seen.push_back(c->conv_backend());
      if (const auto* r = m->as<ResampleImpl>()) {
        if (r->mode() == ResampleMode::upsample2d || r->mode() == ResampleMode::upsample3d) {
          ++upsamples;
          seen.push_back(r->subpixel_upsample() ? "subpixel" : "nearest");
        }
      }
    }
    REQUIRE(upsamples == expected_upsamples);
    std::sort(seen.begin(), seen.end());
    seen.erase(std::unique(seen.begin(), seen.end()), seen.end());
    return seen;
  };
  // (The scene decoder upsamples twice, in time and space; its last x2 is gone.)
  CHECK(kernels_of(*fast, 2) == std::vector<std::string>{"auto", "fused", "subpixel"});
  CHECK(kernels_of(*reference, 2) == std::vector<std::string>{"aten", "cudnn", "nearest"});
  // The Wan VAE (encoder and decoder) takes the same choices.
  WanVAE vae(cfg.vae, cfg.kernels);
  CHECK(kernels_of(*vae, 3) == std::vector<std::string>{"aten", "cudnn", "nearest"});

  torch::NoGradGuard no_grad;
  auto latent = torch::randn({1, 16, 3, 2, 3});
  auto cams = torch::randn({1, 32, 3, 2, 3});
  for (const bool streaming : {false, true}) {
    INFO("streaming " << streaming);
    auto a = fast->forward(latent, cams, streaming), b = reference->forward(latent, cams, streaming);
    REQUIRE(a.sizes() == b.sizes());
    CHECK(flat::test::rel_error(b, a) < 1e-5);
  }

  // An unknown backend is a config error naming the key and the valid names,
  // whether it comes from YAML or from a config built in code.
  REQUIRE_THROWS_WITH(flat::config::parse<SceneDecoderConfig>("kernels: {conv_backend: fastest}\n", "model.yaml"),
                      FLAT_CONTAINS("model.yaml: 'kernels.conv_backend': expected one of {auto, cudnn") &&
                          FLAT_CONTAINS("got 'fastest'"));
  SceneDecoderConfig bad = tiny_config();
  bad.kernels.conv_backend = "fastest";
  REQUIRE_THROWS_WITH(SceneDecoder(bad), FLAT_CONTAINS("SceneDecoderConfig: 'kernels.conv_backend'"));
  REQUIRE_THROWS_WITH(flat::config::parse<SceneDecoderConfig>("kernels: {fused_norm: maybe}\n", "model.yaml"),
                      FLAT_CONTAINS("kernels.fused_norm"));
}

TEST_CASE("RMS_norm + SiLU matches its definition; gradient vs finite differences", "[model][scene]") {
  auto x = torch::randn({1, 4, 2, 2, 3}, torch::kDouble);
  auto gamma = torch::rand({4, 1, 1, 1}, torch::kDouble) + 0.5;
  auto ref = torch::silu(x / x.norm(2, 1, true) * 2.0 * gamma);
  auto got = rms_norm_silu_padded(x, gamma, 2);
  CHECK(got.size(2) == 4);
  CHECK(got.narrow(2, 0, 2).abs().max().item<double>() == 0.0);
  CHECK(flat::test::rel_error(got.narrow(2, 2, 2), ref) < 1e-12);
  // Gradient of the differentiable path against central differences (double).
  auto xg = x.clone().requires_grad_(true);
  auto w = torch::randn({1, 4, 4, 2, 3}, torch::kDouble);
  (rms_norm_silu_padded(xg, gamma, 2) * w).sum().backward();
  const double eps = 1e-6;
  for (int64_t i : {0, 7, 19, 40}) {
    auto xp = x.clone(), xm = x.clone();
    xp.view(-1)[i] += eps;
    xm.view(-1)[i] -= eps;
    double fd = ((rms_norm_silu_padded(xp, gamma, 2) * w).sum().item<double>() -
                 (rms_norm_silu_padded(xm, gamma, 2) * w).sum().item<double>()) / (2 * eps);
    CHECK(xg.grad().view(-1)[i].item<double>() == Approx(fd).epsilon(1e-6));
  }
}

TEST_CASE("Camera latents: RPPC halves encoded separately, cached on disk", "[model][scene]") {
  torch::manual_seed(9);
  WanVAEConfig vc;
  vc.dim = 8;
  WanVAE vae(vc);
  auto cams = orbit(5);
  auto lat = encode_camera_latents(vae, cams, 16, 24);
  REQUIRE(lat.sizes() == at::IntArrayRef({1, 32, 2, 2, 3}));
  auto [ref, dir] = ray_videos(cams, 16, 24);
  torch::NoGradGuard no_grad;
  CHECK(flat::test::rel_error(lat.narrow(1, 0, 16), vae->encode(ref)) < 1e-6);
  CHECK(flat::test::rel_error(lat.narrow(1, 16, 16), vae->encode(dir)) < 1e-6);
  CHECK(flat::test::rel_error(encode_camera_latents(vae, cams, 16, 24, false), lat) < 1e-5);
  auto dir_path = flat::test::scratch_dir("model_camera_latents");
  save_camera_latents((dir_path / "cam.safetensors").string(), lat, 16, 24);
  CHECK(torch::equal(load_camera_latents((dir_path / "cam.safetensors").string()), lat));
  REQUIRE_THROWS_WITH(encode_camera_latents(vae, orbit(4), 16, 24), FLAT_CONTAINS("1+4k"));
}

TEST_CASE("Fusion ablation: without zero-init the camera term changes the output from the start", "[model][scene]") {
  torch::manual_seed(8);
  auto cfg = tiny_config();
  cfg.adapter_zero_init = false;
  SceneDecoder scene(cfg);
  CHECK(scene->adapter->zero_conv->weight.abs().sum().item<double>() > 0.0);
  torch::NoGradGuard no_grad;
  auto latent = torch::randn({1, 16, 2, 2, 2});
  auto cams = torch::randn({1, 32, 2, 2, 2});
  CHECK((scene->forward(latent, cams) - scene->forward(latent)).abs().max().item<double>() > 1e-4);
}

TEST_CASE("Camera latents of the conditioning ablation: Plucker rays (o x d, d)", "[model][scene]") {
  flat::camera::Cameras cams;
  cams.intrinsics = torch::tensor({0.8, 1.0, 0.5, 0.5}, torch::kFloat).repeat({5, 1});
  cams.c2w = torch::eye(4).repeat({5, 1, 1});
  cams.c2w.select(2, 3).narrow(1, 0, 3).copy_(torch::tensor({1.0f, -2.0f, 0.5f}));
  auto [ref, dir] = ray_videos(cams, 8, 16, "plucker");
  auto [rref, rdir] = ray_videos(cams, 8, 16, "rppc");
  CHECK(torch::equal(dir, rdir));  // both carry the direction second
  // moment = o x d: orthogonal to d, and not the RPPC point.
  CHECK((ref * dir).sum(1).abs().max().item<float>() < 1e-5);
  CHECK((ref - rref).abs().max().item<float>() > 0.1);
  REQUIRE_THROWS_WITH(ray_videos(cams, 8, 16, "pluecker"), FLAT_CONTAINS("rppc or plucker"));
}
