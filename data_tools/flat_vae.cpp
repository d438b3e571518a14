// flat_vae: encode videos to Wan 2.1 latents and decode latents to videos.
//
//   flat_vae encode --weights Wan2.1_VAE.safetensors --in frames/ --out latents.safetensors
//   flat_vae decode --weights Wan2.1_VAE.safetensors --in latents.safetensors --out video.safetensors
//
// encode: --in is an image folder (sorted by name) or a safetensors file with
// tensor `video` (B,3,F,H,W) in [-1,1]; writes `latent` (B,16,T',H/8,W/8), the
// normalised mean. decode: reads `latent`, writes `video` (B,3,F,H,W) in [-1,1]
// to a .safetensors file, or PNG frames (B=1) to a folder. Weights in the
// original Wan or the diffusers naming are detected; --random-weights --seed S
// runs without a checkpoint. Outputs record in their metadata whether the
// weights were pretrained or random.
#include <filesystem>

#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/progress.h"
#include "flat/core/shape.h"
#include "flat/core/tensor_io.h"
#include "flat/model/wan_vae.h"
#include "flat/model/weights.h"

namespace fs = std::filesystem;
using namespace flat;
using namespace flat::model;

namespace {

struct Options {
  std::string weights, in, out, mode = "streaming", device = "cpu", dtype = "fp32";
  bool random_weights = false, trim = false, no_clamp = false;
  int64_t seed = 0, dim = 96;
};

void add_common(CLI::App* cmd, Options& o) {
  cmd->add_option("--weights", o.weights, "VAE weights (.safetensors, Wan or diffusers naming)");
  cmd->add_flag("--random-weights", o.random_weights, "use randomly initialised weights (testing without a checkpoint)");
  cmd->add_option("--seed", o.seed, "seed for --random-weights")->capture_default_str();
  cmd->add_option("--in", o.in, "input")->required();
  cmd->add_option("--out", o.out, "output")->required();
  cmd->add_option("--mode", o.mode, "streaming (bounded memory) or full (whole sequence at once)")
      ->check(CLI::IsMember({"streaming", "full"}))
      ->capture_default_str();
  cmd->add_option("--device", o.device, "cpu or cuda")->check(CLI::IsMember({"cpu", "cuda"}))->capture_default_str();
  cmd->add_option("--dtype", o.dtype, "fp32 or bf16")->check(CLI::IsMember({"fp32", "bf16"}))->capture_default_str();
  cmd->add_option("--dim", o.dim, "base width (96 = pretrained Wan 2.1; smaller only with --random-weights)")
      ->capture_default_str();
}

// The VAE on the requested device and dtype, plus the metadata describing its weights.
WanVAE make_vae(const Options& o, Metadata& meta) {
  FLAT_CHECK(o.random_weights != !o.weights.empty(), "flat_vae: give exactly one of --weights FILE or --random-weights");
  FLAT_CHECK(o.weights.empty() || o.dim == 96, "flat_vae: --dim applies only to --random-weights");
  if (o.device == "cuda") FLAT_CHECK(torch::cuda::is_available(), "flat_vae: --device cuda but no CUDA device is available");
  WanVAEConfig config;
  config.dim = o.dim;
  if (o.random_weights) torch::manual_seed(o.seed);
  WanVAE vae(config);
  if (o.random_weights) {
    meta["weights"] = "random";
    meta["seed"] = std::to_string(o.seed);
    spdlog::warn("flat_vae: RANDOM weights (seed {}): outputs are not meaningful images", o.seed);
  } else {
    auto report = load_weights(*vae, o.weights);
    meta["weights"] = "pretrained";
    meta["weights_file"] = fs::path(o.weights).filename().string();
    meta["weights_naming"] = naming_name(report.naming);
  }
  vae->eval();
  if (o.device == "cuda") at::globalContext().setBenchmarkCuDNN(true);  // conv autotuning
  vae->to(o.device == "cuda" ? torch::kCUDA : torch::kCPU, o.dtype == "bf16" ? torch::kBFloat16 : torch::kFloat);
  meta["mode"] = o.mode;
  meta["dtype"] = o.dtype;
  return vae;
}

at::Tensor read_video(const Options& o) {
  if (fs::is_directory(o.in)) {
    auto files = list_images(o.in);
    FLAT_CHECK(!files.empty(), "flat_vae: no images in folder " + o.in);
    std::vector<at::Tensor> frames;
    Progress progress("reading frames", int64_t(files.size()));
    for (const auto& f : files) {
      at::Tensor img = read_image(f);
      FLAT_CHECK(img.size(0) >= 3, "flat_vae: " + f + ": need an RGB image, got " + shape_str(img));
      img = img.narrow(0, 0, 3);
      FLAT_CHECK(frames.empty() || img.sizes() == frames[0].sizes(),
                 "flat_vae: " + f + ": size " + shape_str(img) + " differs from the first frame " + shape_str(frames[0]));
      frames.push_back(img);
      progress.step();
    }
    return (at::stack(frames, 1).unsqueeze(0) * 2 - 1);  // (1,3,F,H,W) in [-1,1]
  }
  return load_tensor_checked(o.in, "video", {-1, 3, -1, -1, -1}, "(B,3,F,H,W)").to(at::kFloat);
}

void encode(const Options& o) {
  Metadata meta;
  at::Tensor video = read_video(o);
  check_finite(video, o.in + ": video");
  const int64_t F = video.size(2);
  if ((F - 1) % 4 != 0) {
    const int64_t keep = 1 + 4 * ((F - 1) / 4);
    FLAT_CHECK(o.trim, "flat_vae: " + o.in + " has " + std::to_string(F) +
                           " frames; the Wan VAE needs 1+4k (e.g. " + std::to_string(keep) + " or " +
                           std::to_string(keep + 4) + "). Pass --trim to keep the first " + std::to_string(keep));
    spdlog::warn("flat_vae: trimming {} frames to {} (dropping the last {})", F, keep, F - keep);
    video = video.narrow(2, 0, keep);
    meta["trimmed_from_frames"] = std::to_string(F);
  }
  FLAT_CHECK(video.size(3) % 8 == 0 && video.size(4) % 8 == 0,
             "flat_vae: height and width must be multiples of 8, got " + shape_str(video));
  WanVAE vae = make_vae(o, meta);
  auto weight = vae->conv2->weight;
  torch::NoGradGuard no_grad;
  std::vector<at::Tensor> latents;
  Progress progress("encoding", video.size(0));
  for (int64_t b = 0; b < video.size(0); ++b) {
    at::Tensor v = video.narrow(0, b, 1).to(weight.device(), weight.scalar_type());
    latents.push_back(vae->encode(v, o.mode == "streaming").to(at::kCPU, at::kFloat));
    progress.step();
  }
  progress.finish();
  at::Tensor latent = at::cat(latents, 0);
  meta["frames"] = std::to_string(video.size(2));
  meta["height"] = std::to_string(video.size(3));
  meta["width"] = std::to_string(video.size(4));
  meta["latent"] = "normalised mu: (mu - mean) / std";
  save_safetensors(o.out, {{"latent", latent}}, meta);
  spdlog::info("flat_vae: wrote latent {} to {}", shape_str(latent), o.out);
}

void decode(const Options& o) {
  Metadata meta;
  at::Tensor latent = load_tensor_checked(o.in, "latent", {-1, 16, -1, -1, -1}, "(B,16,T',h,w)").to(at::kFloat);
  check_finite(latent, o.in + ": latent");
  WanVAE vae = make_vae(o, meta);
  auto weight = vae->conv2->weight;
  torch::NoGradGuard no_grad;
  std::vector<at::Tensor> videos;
  Progress progress("decoding", latent.size(0));
  for (int64_t b = 0; b < latent.size(0); ++b) {
    at::Tensor z = latent.narrow(0, b, 1).to(weight.device(), weight.scalar_type());
    videos.push_back(vae->decode(z, o.mode == "streaming", !o.no_clamp).to(at::kCPU, at::kFloat));
    progress.step();
  }
  progress.finish();
  at::Tensor video = at::cat(videos, 0);
  meta["clamped"] = o.no_clamp ? "false" : "true";
  if (fs::path(o.out).extension() == ".safetensors") {
    save_safetensors(o.out, {{"video", video}}, meta);
    spdlog::info("flat_vae: wrote video {} to {}", shape_str(video), o.out);
    return;
  }
  FLAT_CHECK(video.size(0) == 1, "flat_vae: writing frames to a folder needs B = 1, got " + shape_str(video) +
                                     "; use a .safetensors output");
  fs::create_directories(o.out);
  Progress writing("writing frames", video.size(2));
  for (int64_t t = 0; t < video.size(2); ++t) {
    char name[32];
    std::snprintf(name, sizeof(name), "frame_%04lld.png", static_cast<long long>(t));
    write_image((fs::path(o.out) / name).string(), (video[0].select(1, t) + 1) / 2);
    writing.step();
  }
  writing.finish();
  spdlog::info("flat_vae: wrote {} frames to {}", video.size(2), o.out);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"flat_vae: Wan 2.1 VAE encode (video -> normalised latent) and decode (latent -> video)"};
  app.require_subcommand(1);
  Options enc, dec;
  auto* e = app.add_subcommand("encode", "image folder or safetensors `video` (B,3,F,H,W) in [-1,1] -> `latent`");
  add_common(e, enc);
  e->add_flag("--trim", enc.trim, "keep the first 1+4k frames when F is not 1+4k (else refuse)");
  auto* d = app.add_subcommand("decode", "safetensors `latent` (B,16,T',h,w) -> `video` file or PNG frame folder");
  add_common(d, dec);
  d->add_flag("--no-clamp", dec.no_clamp, "keep the raw decoder output (no clamp to [-1,1])");
  try {
    app.parse(argc, argv);
    if (e->parsed()) encode(enc);
    if (d->parsed()) decode(dec);
  } catch (const CLI::ParseError& err) {
    return app.exit(err);
  } catch (...) {
    return flat::report_current_error();
  }
  return 0;
}
