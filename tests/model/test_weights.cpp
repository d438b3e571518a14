// Weight files: both key namings load to identical models, strict loading lists
// every problem, partial loading of the scene decoder from a VAE file.
#include <filesystem>

#include "flat/core/error.h"
#include "flat/core/tensor_io.h"
#include "flat/model/scene_decoder.h"
#include "flat/model/wan_vae.h"
#include "flat/model/weight_names.h"
#include "flat/model/weights.h"
#include "test_support.h"

using namespace flat::model;

namespace {
WanVAEConfig tiny_config() {
  WanVAEConfig c;
  c.dim = 8;
  return c;
}
}  // namespace

TEST_CASE("diffusers key names follow the documented renames", "[model][weights]") {
  // (Wan name, diffusers name), each renamed both ways; heads are not the VAE's and keep their names.
  const std::pair<std::string, std::string> renames[] = {
      {"conv1.weight", "quant_conv.weight"},
      {"conv2.bias", "post_quant_conv.bias"},
      {"decoder.conv1.weight", "decoder.conv_in.weight"},
      {"decoder.head.0.gamma", "decoder.norm_out.gamma"},
      {"decoder.head.2.weight", "decoder.conv_out.weight"},
      {"decoder.middle.0.residual.0.gamma", "decoder.mid_block.resnets.0.norm1.gamma"},
      {"decoder.middle.2.residual.6.bias", "decoder.mid_block.resnets.1.conv2.bias"},
      {"decoder.middle.1.to_qkv.weight", "decoder.mid_block.attentions.0.to_qkv.weight"},
      {"encoder.downsamples.3.shortcut.weight", "encoder.down_blocks.3.conv_shortcut.weight"},
      {"encoder.downsamples.5.time_conv.weight", "encoder.down_blocks.5.time_conv.weight"},
      {"decoder.upsamples.4.residual.2.weight", "decoder.up_blocks.1.resnets.0.conv1.weight"},
      {"decoder.upsamples.14.residual.3.gamma", "decoder.up_blocks.3.resnets.2.norm2.gamma"},
      {"decoder.upsamples.7.resample.1.weight", "decoder.up_blocks.1.upsamplers.0.resample.1.weight"},
      {"heads.depth.2.weight", "heads.depth.2.weight"}};
  for (const auto& [wan, diffusers] : renames) {
    CHECK(wan_to_diffusers(wan) == diffusers);
    CHECK(diffusers_to_wan(diffusers) == wan);
  }
  // Every key of the VAE survives the round trip, and the naming is detected.
  WanVAE vae(tiny_config());
  std::vector<std::string> wan_keys, diff_keys;
  for (const auto& p : vae->named_parameters()) {
    wan_keys.push_back(p.key());
    diff_keys.push_back(wan_to_diffusers(p.key()));
    CHECK(diffusers_to_wan(diff_keys.back()) == p.key());
  }
  CHECK(detect_naming(wan_keys) == WeightNaming::wan);
  CHECK(detect_naming(diff_keys) == WeightNaming::diffusers);
}

TEST_CASE("Files saved with either naming load to identical outputs", "[model][weights]") {
  torch::manual_seed(5);
  WanVAE source(tiny_config());
  auto dir = flat::test::scratch_dir("model_weights_naming");
  const std::string wan_file = (dir / "wan.safetensors").string();
  const std::string diff_file = (dir / "diffusers.safetensors").string();
  save_weights(*source, wan_file, WeightNaming::wan);
  save_weights(*source, diff_file, WeightNaming::diffusers);
  CHECK(flat::load_safetensors(diff_file).count("decoder.up_blocks.1.resnets.0.conv1.weight") == 1);

  torch::manual_seed(6);
  WanVAE a(tiny_config()), b(tiny_config());
  auto ra = load_weights(*a, wan_file);
  auto rb = load_weights(*b, diff_file);
  CHECK(ra.naming == WeightNaming::wan);
  CHECK(rb.naming == WeightNaming::diffusers);
  CHECK(ra.loaded.size() == source->parameters().size());
  torch::NoGradGuard no_grad;
  auto latent = torch::randn({1, 16, 2, 2, 2});
  auto expected = source->decode(latent, false);
  CHECK(torch::equal(a->decode(latent, false), expected));
  CHECK(torch::equal(b->decode(latent, false), expected));
}

TEST_CASE("Strict loading names every missing, unexpected and wrong-shape tensor", "[model][weights]") {
  WanVAE source(tiny_config());
  auto tensors = state_tensors(*source, WeightNaming::wan);
  tensors.erase("decoder.middle.1.proj.bias");
  tensors["decoder.extra.weight"] = torch::zeros({3});
  tensors["decoder.conv1.weight"] = torch::zeros({1, 2, 3});
  auto dir = flat::test::scratch_dir("model_weights_strict");
  const std::string file = (dir / "bad.safetensors").string();
  flat::save_safetensors(file, tensors);
  WanVAE target(tiny_config());
  const auto before = target->decoder->mid1->conv1->weight.clone();
  try {
    load_weights(*target, file);
    FAIL("expected flat::Error");
  } catch (const flat::Error& e) {
    const std::string msg = e.what();
    CHECK(msg.find("bad.safetensors") != std::string::npos);
    CHECK(msg.find("missing (1): decoder.middle.1.proj.bias") != std::string::npos);
    CHECK(msg.find("unexpected (1): decoder.extra.weight") != std::string::npos);
    CHECK(msg.find("wrong shape (1): decoder.conv1.weight: file (1,2,3)") != std::string::npos);
  }
  // Nothing was modified by the failed load.
  CHECK(torch::equal(target->decoder->mid1->conv1->weight, before));
}

TEST_CASE("Scene decoder initialises from a full VAE file (RGB head absent)", "[model][weights]") {
  WanVAE source(tiny_config());
  auto dir = flat::test::scratch_dir("model_weights_scene");
  const std::string file = (dir / "vae.safetensors").string();
  save_weights(*source, file, WeightNaming::diffusers);
  SceneDecoderConfig config;
  config.vae = tiny_config();
  SceneDecoder scene(config);
  auto report = scene->load_pretrained_vae(file);
  CHECK(!report.initialised.empty());
  CHECK(!report.skipped.empty());
  auto src = source->named_parameters();
  for (const auto& p : scene->named_parameters()) {
    if (p.key().rfind("decoder.", 0) == 0 || p.key().rfind("conv2.", 0) == 0) {
      INFO(p.key());
      CHECK(torch::equal(p.value(), src[p.key()]));
    }
  }
  // Strict loading of the same file into the scene decoder refuses, naming the RGB head.
  SceneDecoder strict(config);
  REQUIRE_THROWS_WITH(load_weights(*strict, file), FLAT_CONTAINS("decoder.head.2.weight"));
}

TEST_CASE("Weights as other tools save them: a diffusers folder, a common key prefix", "[model][weights]") {
  torch::manual_seed(7);
  WanVAE source(tiny_config());
  auto dir = flat::test::scratch_dir("model_weights_other_tools");
  // A diffusers folder: the file inside is found.
  std::filesystem::create_directories(dir / "vae");
  save_weights(*source, (dir / "vae" / "diffusion_pytorch_model.safetensors").string(), WeightNaming::diffusers);
  CHECK(resolve_weights_file((dir / "vae").string()) == (dir / "vae" / "diffusion_pytorch_model.safetensors").string());
  WanVAE a(tiny_config());
  load_weights(*a, (dir / "vae").string());
  auto sp = source->named_parameters(), ap = a->named_parameters();
  for (const auto& p : sp) CHECK(torch::equal(p.value(), ap[p.key()]));
  // Keys under "vae." (a bundle of several models): detected and stripped.
  flat::TensorMap prefixed;
  for (const auto& [k, v] : state_tensors(*source)) prefixed.emplace("vae." + k, v);
  flat::save_safetensors((dir / "bundle.safetensors").string(), prefixed);
  WanVAE b(tiny_config());
  auto report = load_weights(*b, (dir / "bundle.safetensors").string());
  CHECK(report.loaded.size() == sp.size());
  auto bp = b->named_parameters();
  for (const auto& p : sp) CHECK(torch::equal(p.value(), bp[p.key()]));
  // An explicit prefix works the same, and a wrong one names the key at fault.
  WanVAE c(tiny_config());
  LoadSpec spec;
  spec.strip_prefix = "vae.";
  CHECK(load_weights(*c, (dir / "bundle.safetensors").string(), spec).loaded.size() == sp.size());
  spec.strip_prefix = "model.";
  REQUIRE_THROWS_WITH(load_weights(*c, (dir / "bundle.safetensors").string(), spec),
                      FLAT_CONTAINS("does not start with the prefix 'model.'"));
  // A folder with no weights file, or two candidates, is named.
  std::filesystem::create_directories(dir / "empty");
  REQUIRE_THROWS_WITH(resolve_weights_file((dir / "empty").string()), FLAT_CONTAINS("without a .safetensors file"));
}

TEST_CASE("Weights files that are not weights are refused with the tensor named", "[model][weights]") {
  auto dir = flat::test::scratch_dir("model_weights_bad");
  WanVAE vae(tiny_config());
  auto good = state_tensors(*vae);
  auto nan = good;
  nan.begin()->second = torch::full_like(nan.begin()->second, NAN);
  flat::save_safetensors((dir / "nan.safetensors").string(), nan);
  REQUIRE_THROWS_WITH(load_weights(*vae, (dir / "nan.safetensors").string()),
                      FLAT_CONTAINS(nan.begin()->first) && FLAT_CONTAINS("non-finite"));
  auto u8 = good;
  u8.begin()->second = torch::zeros_like(u8.begin()->second, torch::kByte);
  flat::save_safetensors((dir / "u8.safetensors").string(), u8);
  REQUIRE_THROWS_WITH(load_weights(*vae, (dir / "u8.safetensors").string()), FLAT_CONTAINS("floating point"));
  // No key matches at all: one hint instead of only the long lists.
  flat::TensorMap foreign;
  for (const auto& [k, v] : good) foreign.emplace("unet.blocks." + k, v);
  foreign.emplace("text.weight", torch::zeros({2}));  // not one common prefix
  flat::save_safetensors((dir / "foreign.safetensors").string(), foreign);
  REQUIRE_THROWS_WITH(load_weights(*vae, (dir / "foreign.safetensors").string()), FLAT_CONTAINS("--vae-prefix"));
}
