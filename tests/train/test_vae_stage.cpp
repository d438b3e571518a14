// The VAE stage (task: vae) end to end, as separate processes on the tiny
// synthetic rooms of train_fixtures.h: it learns to reconstruct held-out
// windows, its vae.safetensors is read by flat_vae (and gives the same
// reconstruction), and a SIGKILLed run resumes bit for bit.
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include "flat/core/tensor_io.h"
#include "flat/data/scene.h"
#include "flat/data/scene_frames.h"
#include "flat/eval/image_metrics.h"
#include "flat/model/wan_vae.h"
#include "flat/model/weights.h"
#include "support/process.h"
#include "test_support.h"
#include "train_fixtures.h"

namespace fs = std::filesystem;
using namespace flat::test;

namespace {

// A tiny VAE stage on the fixtures' rooms (32x48, windows of 5 frames).
std::string write_vae_config(const std::string& dir, int steps, int val_samples = 1) {
  const std::string& data = tiny_data();
  const std::string path = dir + "/config.yaml";
  std::ofstream(path) << tiny_run_yaml(dir, "stage: tiny-vae\ntask: vae", steps)
                      << "validation: {datasets: [{root: " << data << "/val}], every: " << steps
                      << ", scenes: " << val_samples << ", grid_views: 2}\n"
                      << "data: {datasets: [{root: " << data << "/train}], height: 32, width: 48, input_frames: 5, "
                      << "target_views: 1, workers: 1, depth: false, normals: false, input_images: true, "
                      << "latents: false}\n"
                      << "vae: {l1: 1.0, l2: 1.0, kl: 1.0e-6, stats_samples: 4}\n";
  return path;
}

}  // namespace

TEST_CASE("VAE stage: it learns to reconstruct, and its file round-trips through flat_vae", "[train][vae]") {
  const std::string d = fresh_dir("vae_learns").string();
  const int rc = train({"--config", write_vae_config(d, 60)}, d + "/log.txt");
  const std::string log = read_file(d + "/log.txt");
  INFO(log);
  REQUIRE(rc == 0);
  auto r = rows(d + "/run");
  REQUIRE(r.size() == 60);
  check_loss_fell(r, "l1");
  auto val = rows(d + "/run", "val");
  REQUIRE(val.size() == 2);
  const double before = val[0].at("val_psnr").get<double>(), after = val[1].at("val_psnr").get<double>();
  INFO("held-out reconstruction PSNR " << before << " -> " << after);
  CHECK(after > before + 3.0);
  CHECK(val[1].contains("val_mean_colour_psnr"));
  CHECK_FALSE(val[1].contains("val_latent_correlation"));  // one held-out sample: no pair to correlate
  const std::string vae = d + "/run/vae.safetensors";
  REQUIRE(fs::exists(vae));
  CHECK_FALSE(fs::exists(d + "/run/model.safetensors"));
  CHECK(log.find("reconstruction PSNR") != std::string::npos);

  // The held-out window through flat_vae encode and decode with the file: the
  // reconstruction equals the trainer's validation of the same frames.
  const auto scene_dir = flat::data::scene_dirs_under(tiny_data() + "/val").front();
  auto scene = flat::data::read_scene(scene_dir);
  auto frames = flat::data::load_frames(scene, {0, 1, 2, 3, 4}, false, false).images;  // (5,3,32,48)
  auto video = (frames.permute({1, 0, 2, 3}).unsqueeze(0) * 2 - 1).contiguous();
  flat::save_safetensors(d + "/video.safetensors", {{"video", video}});
  REQUIRE(run({binary("flat_vae"), "encode", "--vae", vae, "--in", d + "/video.safetensors", "--out",
               d + "/latent.safetensors", "--mode", "full"},
              d + "/encode.txt") == 0);
  REQUIRE(run({binary("flat_vae"), "decode", "--vae", vae, "--in", d + "/latent.safetensors", "--out",
               d + "/recon.safetensors", "--mode", "full"},
              d + "/decode.txt") == 0);
  auto latent = flat::load_safetensors(d + "/latent.safetensors").at("latent");
  auto recon = flat::load_safetensors(d + "/recon.safetensors").at("video");
  REQUIRE(recon.sizes() == video.sizes());
  // Normalised latents: the statistics folded into the file make them about zero-mean, unit-spread.
  INFO("latent mean " << latent.mean().item<double>() << ", std " << latent.std().item<double>());
  CHECK(std::abs(latent.mean().item<double>()) < 0.5);
  CHECK(latent.std().item<double>() > 0.3);
  CHECK(latent.std().item<double>() < 3.0);
  // The same frames through the trainer's own (unfolded) weights of the last
  // checkpoint: flat_vae with the folded file must reconstruct them alike.
  flat::model::WanVAEConfig config;
  config.dim = 4;
  flat::model::WanVAE raw(config);
  flat::model::load_state(*raw, flat::load_safetensors(d + "/run/checkpoints/step_00000060/model.safetensors"), {},
                          "checkpoint");
  raw->eval();
  torch::NoGradGuard no_grad;
  auto mu = raw->encode_moments(video, false).narrow(1, 0, 16);
  auto expected = raw->decoder->forward(raw->conv2->forward(mu)).clamp(-1, 1);
  INFO("flat_vae vs the trainer's weights: relative error " << rel_error(recon, expected));
  CHECK(rel_error(recon, expected) < 1e-4);
  auto to_frames = [](const at::Tensor& v) { return ((v[0].permute({1, 0, 2, 3}) + 1) * 0.5).clamp(0, 1); };
  const double psnr = flat::eval::psnr(to_frames(recon), to_frames(video)).mean().item<double>();
  INFO("flat_vae reconstruction PSNR " << psnr << " dB, the trainer's validation " << after << " dB");
  CHECK(psnr > before + 3.0);

  // flat_latents --vae reads the same file (its width from the file) and
  // stores the same latent for the scene's first window, recorded as pretrained.
  const std::string copy = d + "/val_copy";
  fs::copy(scene_dir, copy, fs::copy_options::recursive);
  // The copy holds random-encoder latents of the same set: replacing them takes --overwrite.
  REQUIRE(run({binary("flat_latents"), "--scenes", copy, "--vae", vae, "--window", "5"}, d + "/latents_refused.txt") ==
          1);
  CHECK_THAT(read_file(d + "/latents_refused.txt"), FLAT_CONTAINS("--overwrite replaces it"));
  REQUIRE(run({binary("flat_latents"), "--scenes", copy, "--vae", vae, "--window", "5", "--overwrite"},
              d + "/latents.txt") == 0);
  auto rescanned = flat::data::read_scene(copy);
  CHECK(rescanned.latents.encoder == "pretrained");
  auto stored = flat::load_safetensors(copy + "/" + rescanned.latents.file).at("video.0");
  CHECK(rel_error(stored, latent[0]) < 1e-4);
  CHECK(rescanned.latents.weights_digest.size() == 16);

  // The same file again: already present, nothing rewritten. A retrained VAE
  // under the same file name: its latents are not taken for the old ones.
  const std::string latent_file = copy + "/" + rescanned.latents.file;
  const std::string bytes = read_file(latent_file);
  REQUIRE(run({binary("flat_latents"), "--scenes", copy, "--vae", vae, "--window", "5"}, d + "/latents_again.txt") == 0);
  CHECK_THAT(read_file(d + "/latents_again.txt"), FLAT_CONTAINS("1 already present"));
  CHECK(read_file(latent_file) == bytes);
  flat::Metadata meta;
  auto weights = flat::load_safetensors(vae, &meta);
  for (auto& [name, t] : weights)
    if (t.is_floating_point()) {
      t = t + 0.01;  // a different VAE of the same shape
      break;
    }
  fs::create_directories(d + "/retrained");
  const std::string other = d + "/retrained/" + fs::path(vae).filename().string();
  flat::save_safetensors(other, weights, meta);
  REQUIRE(run({binary("flat_latents"), "--scenes", copy, "--vae", other, "--window", "5"}, d + "/latents_other.txt") ==
          1);
  CHECK_THAT(read_file(d + "/latents_other.txt"), FLAT_CONTAINS("other weights of the same name"));
  CHECK(read_file(latent_file) == bytes);
}

TEST_CASE("VAE stage: killed with SIGKILL, --resume continues bit for bit", "[train][vae]") {
  const std::string ref = fresh_dir("vae_reference").string();
  REQUIRE(train({"--config", write_vae_config(ref, 40, 2)}, ref + "/log.txt") == 0);
  const auto reference = losses(ref + "/run");
  REQUIRE(reference.size() == 40);

  // Two held-out samples this time: the latents' spread across them is logged.
  CHECK(rows(ref + "/run", "val").back().contains("val_latent_correlation"));

  const std::string d = fresh_dir("vae_kill").string();
  auto child = spawn({binary("flat_train"), "--config", write_vae_config(d, 40, 2)}, d + "/log1.txt");
  REQUIRE(child.pid > 0);
  REQUIRE(wait_until([&] { return count_lines(d + "/run/metrics/train.jsonl") >= 3; }, 300));
  kill(child.pid, SIGKILL);
  REQUIRE(wait_for(child) == 128 + SIGKILL);
  const int rc = train({"--resume", d + "/run"}, d + "/log2.txt");
  INFO(read_file(d + "/log2.txt"));
  REQUIRE(rc == 0);
  CHECK(losses(d + "/run") == reference);
  // The written VAE is the same file content as the uninterrupted run's.
  auto a = flat::load_safetensors(ref + "/run/vae.safetensors");
  auto b = flat::load_safetensors(d + "/run/vae.safetensors");
  REQUIRE(a.size() == b.size());
  for (const auto& [name, t] : a) CHECK(torch::equal(t, b.at(name)));
}
