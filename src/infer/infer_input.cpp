#include "flat/infer/infer_input.h"

#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/camera/camera_json.h"
#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/core/tensor_io.h"
#include "flat/data/scene.h"
#include "flat/data/scene_latents.h"
#include "flat/model/camera_latents.h"
#include "flat/model/wan_vae.h"
#include "flat/model/weights.h"

namespace flat::infer {

namespace {

int64_t frames_of(int64_t latent_frames) { return 1 + 4 * (latent_frames - 1); }

InferInput from_scene(const InputSpec& spec) {
  auto scene = data::read_scene(spec.scene_dir, /*check_files=*/false);
  data::choose_latent_set(scene, spec.latent_set);
  FLAT_CHECK(scene.latents.present(), scene.json_path() + ": the scene has no precomputed latents (run flat_latents)");
  const int64_t n = int64_t(scene.latents.windows.size());
  FLAT_CHECK(spec.window >= 0 && spec.window < n, scene.json_path() + ": --window-index " + std::to_string(spec.window) +
                                                      " out of range: the scene has " + std::to_string(n) +
                                                      " latent window(s)");
  auto w = data::read_window_latents(scene, size_t(spec.window), spec.camera_rays);
  const auto& win = scene.latents.windows[size_t(spec.window)];
  std::vector<int64_t> idx;
  for (int64_t i = 0; i < win.count; ++i) idx.push_back(win.start + i);
  InferInput in;
  in.cameras = scene.cameras(idx);
  in.height = scene.latents.height;
  in.width = scene.latents.width;
  in.input.video_latents = w.video.unsqueeze(0).to(at::kFloat);
  in.input.camera_latents = w.camera.defined() ? w.camera.unsqueeze(0).to(at::kFloat) : at::Tensor();
  in.latent_encoder = scene.latents.encoder.empty() ? "unknown" : scene.latents.encoder;
  in.label = "scene " + scene.name + ", window " + std::to_string(spec.window) + " (frames " +
             std::to_string(win.start) + ".." + std::to_string(win.start + win.count - 1) + ")";
  return in;
}

InferInput from_files(const InputSpec& spec) {
  Metadata meta;
  auto tensors = load_safetensors(spec.latents_file, &meta);
  auto it = tensors.find("video");
  if (it == tensors.end()) {
    std::string keys;
    for (const auto& [k, v] : tensors) keys += (keys.empty() ? "" : ", ") + k;
    fail(spec.latents_file + ": no tensor 'video' (the normalised latents (16,T',h,w)); it holds: " +
         (keys.empty() ? "nothing" : keys));
  }
  auto video = it->second;
  // Integer latents are a wrong file, not values to convert.
  for (const char* key : {"video", "camera"})
    if (tensors.count(key) && !tensors.at(key).is_floating_point())
      fail(spec.latents_file + ": '" + key + "' has dtype " + std::string(c10::toString(tensors.at(key).scalar_type())) +
           "; latents must be floating point (float32, bfloat16 or float16)");
  const bool ok = (video.dim() == 4 && video.size(0) == 16) || (video.dim() == 5 && video.size(0) == 1 && video.size(1) == 16);
  if (!ok)
    fail(spec.latents_file + ": 'video': expected shape (16,T',h,w) or (1,16,T',h,w), got " + shape_str(video));
  if (video.dim() == 4) video = video.unsqueeze(0);
  FLAT_CHECK(at::isfinite(video.to(at::kFloat)).all().item<bool>(),
             spec.latents_file + ": 'video' holds NaN or infinite values");
  auto set = camera::read_cameras_json(spec.cameras_file);
  InferInput in;
  in.cameras = set.cameras;
  const int64_t Tl = video.size(2), T = frames_of(Tl);
  if (in.cameras.size() != T)
    fail(spec.latents_file + " has " + std::to_string(Tl) + " latent frames, which decode to " + std::to_string(T) +
         " frames, but " + spec.cameras_file + " has " + std::to_string(in.cameras.size()) +
         " cameras (a trajectory of T frames needs T' = 1 + (T-1)/4 latent frames)");
  in.height = video.size(3) * 8;
  in.width = video.size(4) * 8;
  if (set.width != in.width || set.height != in.height)
    spdlog::info("{}: cameras are for {}x{} images, the latents decode to {}x{}; the normalised intrinsics are used "
                 "as they are",
                 spec.cameras_file, set.width, set.height, in.width, in.height);
  in.input.video_latents = video.to(at::kFloat);
  auto cam = tensors.find("camera");
  if (cam != tensors.end()) {
    auto c = cam->second.dim() == 4 ? cam->second.unsqueeze(0) : cam->second;
    check_shape(c, {1, 32, Tl, video.size(3), video.size(4)}, spec.latents_file + ": 'camera'",
                "(32,T',h,w) matching 'video'");
    in.input.camera_latents = c.to(at::kFloat);
  } else if (spec.need_camera_latents) {
    FLAT_CHECK(!spec.vae_weights.empty(),
               spec.latents_file + ": no 'camera' latents and the model is camera-conditioned; give the Wan VAE "
                                   "weights with --vae to encode them from " + spec.cameras_file);
    model::WanVAE vae{model::WanVAEConfig{}};
    auto report = model::load_weights(*vae, spec.vae_weights);
    spdlog::info("camera latents: encoding the trajectory with {} ({})", spec.vae_weights, report.summary());
    vae->eval();
    torch::NoGradGuard no_grad;
    in.input.camera_latents =
        model::encode_camera_latents(vae, in.cameras, in.height, in.width, /*streaming=*/true).to(at::kFloat);
  }
  in.label = spec.latents_file + " with " + spec.cameras_file;
  return in;
}

}  // namespace

InferInput load_infer_input(const InputSpec& spec) {
  const bool scene = !spec.scene_dir.empty(), files = !spec.latents_file.empty() || !spec.cameras_file.empty();
  FLAT_CHECK(scene != files, "input: give either a scene folder (--scene) or a latent file and a trajectory "
                             "(--latents and --cameras)");
  if (files)
    FLAT_CHECK(!spec.latents_file.empty() && !spec.cameras_file.empty(),
               "input: --latents and --cameras go together (the trajectory gives the frames' cameras)");
  InferInput in = scene ? from_scene(spec) : from_files(spec);
  const int64_t T = in.cameras.size();
  in.input.input_intrinsics = in.cameras.intrinsics.unsqueeze(0);
  in.input.input_c2w = in.cameras.c2w.unsqueeze(0);
  FLAT_CHECK(T == frames_of(in.input.video_latents.size(2)),
             in.label + ": " + std::to_string(T) + " cameras for " + std::to_string(in.input.video_latents.size(2)) +
                 " latent frames");
  return in;
}

}  // namespace flat::infer
