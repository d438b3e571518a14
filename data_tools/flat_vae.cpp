// flat_vae: encode videos to Wan 2.1 latents and decode latents to videos.
//
//   flat_vae encode --vae Wan2.1_VAE.safetensors --in frames/ --out latents.safetensors
//   flat_vae decode --vae Wan2.1_VAE.safetensors --in latents.safetensors --out video.safetensors
//
// encode: --in is an image folder (sorted by name) or a safetensors file with
// tensor `video` (B,3,F,H,W) in [-1,1]; writes `latent` (B,16,T',H/8,W/8), the
// normalised mean. decode: reads `latent`, writes `video` (B,3,F,H,W) in [-1,1]
// to a .safetensors file, or PNG frames (B=1) to a folder. Weights in the
// original Wan or the diffusers naming are detected (--vae); --random-weights --seed S
// runs without a checkpoint. Outputs record in their metadata whether the
// weights were pretrained or random. An existing output is refused (before any
// work) unless --overwrite; a frame folder appears whole or not at all.
#include <filesystem>
#include <functional>

#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/core/cli.h"
#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/progress.h"
#include "flat/core/shape.h"
#include "flat/core/staged_dir.h"
#include "flat/core/tensor_io.h"
#include "flat/model/wan_vae.h"
#include "flat/model/weights.h"

namespace fs = std::filesystem;
using namespace flat;
using namespace flat::model;

namespace {

struct Options {
  int threads = 0;  // --threads (0: every core)
  std::string weights, weights_prefix, in, out, mode = "streaming", device = "auto", precision = "fp32";
  std::string log_level = "info";
  bool random_weights = false, trim = false, no_clamp = false, overwrite = false;
  int64_t seed = 0, dim = 0;  // 0: 96 with --random-weights, else the weights file's
};

void add_common(CLI::App* cmd, Options& o) {
  cmd->add_option("--vae", o.weights,
                  "VAE weights: .safetensors (Wan or diffusers naming), a diffusers folder, or the vae.safetensors "
                  "of a flat_train VAE stage (the width is read from the file)");
  cmd->add_option("--vae-prefix", o.weights_prefix, "strip this prefix from the --vae file's keys (default: detected)");
  cmd->add_flag("--random-weights", o.random_weights,
                "randomly initialised weights instead of --vae (testing without a checkpoint)");
  cli::add_old_name(*cmd, "--weights", "--vae");
  cli::add_old_name(*cmd, "--weights-prefix", "--vae-prefix");
  cli::add_old_name(*cmd, "--dtype", "--precision");
  cmd->add_option("--seed", o.seed, "seed for --random-weights")->capture_default_str();
  cmd->add_option("--in", o.in, "input file or folder (above)")->required();
  cmd->add_option("--out", o.out, "output (must not exist unless --overwrite)")->required();
  cmd->add_flag("--overwrite", o.overwrite, "replace an existing output (only once the new one is complete)");
  cmd->add_option("--mode", o.mode, "streaming (bounded memory) or full (whole sequence at once)")
      ->check(CLI::IsMember({"streaming", "full"}))
      ->capture_default_str();
  cli::add_device(*cmd, o.device);
  cli::add_threads(*cmd, o.threads);
  cli::add_precision(*cmd, o.precision);
  cmd->add_option("--dim", o.dim, "base width of --random-weights (default 96, as Wan 2.1)")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--log-level", o.log_level, "trace | debug | info | warn | error")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error"}));
}

// Usage checks before any work: one weights source, an output that may be written.
void check_usage(const Options& o, bool decode) {
  if (o.random_weights == !o.weights.empty())
    throw cli::UsageError("flat_vae: give exactly one of --vae FILE or --random-weights");
  if (!o.weights.empty() && o.dim != 0) throw cli::UsageError("flat_vae: --dim applies only to --random-weights");
  const std::string ext = fs::path(o.out).extension().string();
  if (!decode && ext != ".safetensors")
    throw cli::UsageError("flat_vae encode: --out must be a .safetensors file, got '" + o.out + "'");
  if (decode && !ext.empty() && ext != ".safetensors")
    throw cli::UsageError("flat_vae decode: --out must be a .safetensors file or a folder for PNG frames, got '" +
                          o.out + "' (videos: write PNG frames, then encode them with ffmpeg)");
  if (fs::exists(o.out) && !o.overwrite)
    fail(o.out + ": already exists; choose a new output or pass --overwrite");
  std::string log = o.out;
  while (log.size() > 1 && log.back() == '/') log.pop_back();
  cli::start_logging(o.log_level, log + ".log");
}

// The base width: --dim for random weights (default 96), else the weights file's.
int64_t vae_dim(const Options& o) {
  return o.random_weights ? (o.dim > 0 ? o.dim : 96) : vae_dim_of_file(o.weights);
}

// The VAE on the requested device and dtype, plus the metadata describing its weights.
WanVAE make_vae(const Options& o, Metadata& meta) {
  const auto device = cli::resolve_device(o.device);
  WanVAEConfig config;
  config.dim = vae_dim(o);
  if (o.random_weights) torch::manual_seed(o.seed);
  WanVAE vae(config);
  if (o.random_weights) {
    meta["weights"] = "random";
    meta["seed"] = std::to_string(o.seed);
    spdlog::warn("flat_vae: RANDOM weights (seed {}): outputs are not meaningful images", o.seed);
  } else {
    LoadSpec spec;
    spec.strip_prefix = o.weights_prefix;
    auto report = load_weights(*vae, o.weights, spec);
    meta["weights"] = "pretrained";
    meta["weights_file"] = fs::path(o.weights).filename().string();
    meta["weights_naming"] = naming_name(report.naming);
  }
  vae->eval();
  if (device.is_cuda()) at::globalContext().setBenchmarkCuDNN(true);  // conv autotuning
  vae->to(device, cli::precision_dtype(o.precision));
  meta["mode"] = o.mode;
  meta["dtype"] = o.precision;
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
  at::Tensor video = load_tensor_checked(o.in, "video", {-1, 3, -1, -1, -1}, "(B,3,F,H,W)");
  FLAT_CHECK(video.is_floating_point(), "flat_vae: " + o.in + ": video has dtype " +
                                            std::string(c10::toString(video.scalar_type())) +
                                            "; expected floating point values in [-1,1]");
  return video.to(at::kFloat);
}

// Values outside [-1,1] mean another convention ([0,1] is fine, [0,255] is not):
// the encoder would run and write a meaningless latent.
void check_video_range(const at::Tensor& video, const std::string& what) {
  if (video.numel() == 0) return;
  const double lo = video.min().item<double>(), hi = video.max().item<double>();
  if (lo < -1.001 || hi > 1.001)
    fail("flat_vae: " + what + ": values span [" + std::to_string(lo) + ", " + std::to_string(hi) +
         "]; the VAE expects [-1,1] (e.g. 2*x/255-1 for 8-bit values)");
}

// Runs `step` (encode or decode) on each element of the batch in turn, on the
// VAE's device and dtype (one at a time: bounded memory), without gradients;
// returns the results concatenated, float32 on the CPU.
at::Tensor each_batch_element(const at::Tensor& batch, const std::string& what, const WanVAE& vae,
                              const std::function<at::Tensor(const at::Tensor&)>& step) {
  const auto& weight = vae->conv2->weight;
  torch::NoGradGuard no_grad;
  std::vector<at::Tensor> results;
  Progress progress(what, batch.size(0));
  for (int64_t b = 0; b < batch.size(0); ++b) {
    results.push_back(step(batch.narrow(0, b, 1).to(weight.device(), weight.scalar_type())).to(at::kCPU, at::kFloat));
    progress.step();
  }
  progress.finish();
  return at::cat(results, 0);
}

void encode(const Options& o) {
  Metadata meta;
  check_usage(o, false);
  at::Tensor video = read_video(o);
  check_finite(video, o.in + ": video");
  check_video_range(video, o.in + ": video");
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
  // The input plus the encoder's widest activations (dim channels at full size).
  const double frames_in_flight = o.mode == "full" ? double(video.size(2)) : 4.0;
  cli::check_memory(double(video.numel()) * 4.0 + double(video.size(3) * video.size(4)) * 4.0 * 6.0 * double(vae_dim(o)) *
                                                      frames_in_flight,
                    "flat_vae encode of " + shape_str(video), cli::resolve_device(o.device));
  WanVAE vae = make_vae(o, meta);
  at::Tensor latent = each_batch_element(video, "encoding", vae,
                                         [&](const at::Tensor& v) { return vae->encode(v, o.mode == "streaming"); });
  check_finite(latent, "flat_vae: the encoded latent");
  meta["frames"] = std::to_string(video.size(2));
  meta["height"] = std::to_string(video.size(3));
  meta["width"] = std::to_string(video.size(4));
  meta["latent"] = "normalised mu: (mu - mean) / std";
  save_safetensors(o.out, {{"latent", latent}}, meta);
  spdlog::info("flat_vae: wrote latent {} to {}", shape_str(latent), o.out);
}

void decode(const Options& o) {
  Metadata meta;
  check_usage(o, true);
  at::Tensor latent = load_tensor_checked(o.in, "latent", {-1, 16, -1, -1, -1}, "(B,16,T',h,w)");
  FLAT_CHECK(latent.is_floating_point(), "flat_vae: " + o.in + ": latent has dtype " +
                                             std::string(c10::toString(latent.scalar_type())) + "; expected floating point");
  latent = latent.to(at::kFloat);
  check_finite(latent, o.in + ": latent");
  // The decoded video (B,3,1+4(T'-1),8h,8w) in float32, twice (output and the last activations).
  const double frames = double(1 + 4 * (latent.size(2) - 1)), pixels = double(latent.size(3) * latent.size(4) * 64);
  cli::check_memory(double(latent.size(0)) * 3.0 * frames * pixels * 4.0 * 2.0 +
                        pixels * 4.0 * 6.0 * double(vae_dim(o)) * (o.mode == "full" ? frames : 4.0),
                    "flat_vae decode of latent " + shape_str(latent), cli::resolve_device(o.device));
  WanVAE vae = make_vae(o, meta);
  at::Tensor video = each_batch_element(latent, "decoding", vae, [&](const at::Tensor& z) {
    return vae->decode(z, o.mode == "streaming", !o.no_clamp);
  });
  check_finite(video, "flat_vae: the decoded video");
  meta["clamped"] = o.no_clamp ? "false" : "true";
  if (fs::path(o.out).extension() == ".safetensors") {
    save_safetensors(o.out, {{"video", video}}, meta);
    spdlog::info("flat_vae: wrote video {} to {}", shape_str(video), o.out);
    return;
  }
  FLAT_CHECK(video.size(0) == 1, "flat_vae: writing frames to a folder needs B = 1, got " + shape_str(video) +
                                     "; use a .safetensors output");
  // Staged: an earlier folder's frames never stay beside the new ones.
  StagedDir staged(o.out, o.overwrite);
  Progress writing("writing frames", video.size(2));
  for (int64_t t = 0; t < video.size(2); ++t) {
    char name[32];
    std::snprintf(name, sizeof(name), "frame_%04lld.png", static_cast<long long>(t));
    write_image(staged.file(name), (video[0].select(1, t) + 1) / 2);
    writing.step();
  }
  writing.finish();
  staged.commit();
  spdlog::info("flat_vae: wrote {} frames to {}", video.size(2), o.out);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"flat_vae: Wan 2.1 VAE encode (video -> normalised latent) and decode (latent -> video)"};
  app.option_defaults()->always_capture_default();
  app.set_version_flag("--version", std::string("flat_vae ") + cli::kVersion);
  app.require_subcommand(1);
  Options enc, dec;
  auto* e = app.add_subcommand("encode", "image folder or safetensors `video` (B,3,F,H,W) in [-1,1] -> `latent`");
  add_common(e, enc);
  e->add_flag("--trim", enc.trim, "keep the first 1+4k frames when F is not 1+4k (else refuse)");
  auto* d = app.add_subcommand("decode", "safetensors `latent` (B,16,T',h,w) -> `video` file or PNG frame folder");
  add_common(d, dec);
  d->add_flag("--no-clamp", dec.no_clamp, "keep the raw decoder output (no clamp to [-1,1])");
  if (int rc = cli::parse(app, argc, argv); rc >= 0) return rc;
  return cli::run([&] {
    cli::apply_threads(e->parsed() ? enc.threads : dec.threads);
    if (e->parsed()) encode(enc);
    if (d->parsed()) decode(dec);
    return 0;
  });
}
