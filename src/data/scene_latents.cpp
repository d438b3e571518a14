#include "flat/data/scene_latents.h"

#include <unistd.h>

#include <filesystem>

#include "flat/core/error.h"
#include "flat/core/safetensors.h"
#include "flat/core/shape.h"
#include "flat/core/tensor_io.h"

namespace flat::data {

std::string latent_set_file(int64_t height, int64_t width, int64_t frames) {
  return "latents_" + latent_set_key(height, width, frames) + ".safetensors";
}

namespace {

void check_window(const at::Tensor& t, int64_t channels, const LatentInfo& info, const LatentWindow& w,
                  const std::string& what) {
  const int64_t tp = 1 + (w.count - 1) / 4;
  check_shape(t, {channels, tp, info.height / 8, info.width / 8}, what,
              "(" + std::to_string(channels) + ",T',H/8,W/8) with T' = " + std::to_string(tp));
  check_finite(t, what);
}

}  // namespace

StagedLatents stage_scene_latents(const Scene& scene, LatentInfo info, const std::vector<WindowLatents>& latents) {
  FLAT_CHECK(latents.size() == info.windows.size(), scene.json_path() + ": " + std::to_string(latents.size()) +
                                                         " latent windows for " + std::to_string(info.windows.size()) +
                                                         " window entries");
  FLAT_CHECK(info.encoder == "pretrained" || info.encoder == "random",
             "write_scene_latents: encoder must be pretrained or random");
  FLAT_CHECK(!info.windows.empty(), scene.json_path() + ": a latent set needs at least one window");
  info.file = latent_set_file(info.height, info.width, info.frames());
  info.plucker = !latents.empty() && latents[0].camera_plucker.defined();
  TensorMap tensors;
  std::string windows;
  for (size_t i = 0; i < latents.size(); ++i) {
    const auto& w = info.windows[i];
    const std::string k = std::to_string(i);
    check_window(latents[i].video, 16, info, w, scene.name + ": video latent " + k);
    check_window(latents[i].camera, 32, info, w, scene.name + ": camera latent " + k);
    auto type = info.dtype == "bfloat16" ? at::kBFloat16 : info.dtype == "float16" ? at::kHalf : at::kFloat;
    tensors["video." + k] = latents[i].video.to(type).cpu().contiguous();
    tensors["camera." + k] = latents[i].camera.to(type).cpu().contiguous();
    FLAT_CHECK(latents[i].camera_plucker.defined() == latents[0].camera_plucker.defined(),
               scene.name + ": Plucker camera latents for some windows only");
    if (latents[i].camera_plucker.defined()) {
      check_window(latents[i].camera_plucker, 32, info, w, scene.name + ": Plucker camera latent " + k);
      tensors["camera_plucker." + k] = latents[i].camera_plucker.to(type).cpu().contiguous();
    }
    tensors["frames." + k] = at::arange(w.start, w.start + w.count, at::kLong);
    windows += (i ? "," : "") + std::to_string(w.start) + ":" + std::to_string(w.count);
  }
  const std::string staged = scene.path(info.file) + ".staged-" + std::to_string(::getpid());
  save_safetensors(staged, tensors,
                   {{"format", "flat-scene-latents"},
                    {"version", "1"},
                    {"encoder", info.encoder},
                    {"weights", info.weights},
                    {"seed", std::to_string(info.seed)},
                    {"height", std::to_string(info.height)},
                    {"width", std::to_string(info.width)},
                    {"windows", windows}});
  return {staged, info};
}

void commit_scene_latents(Scene& scene, const StagedLatents& staged) {
  // The file a set of this key had before (a version-1 scene's latents.safetensors)
  // goes once scene.json no longer names it; other sets' files are not touched.
  const LatentInfo* old = find_latent_set(scene, staged.info.height, staged.info.width, staged.info.frames());
  const std::string old_file = old && old->file != staged.info.file ? old->file : "";
  std::error_code ec;
  std::filesystem::rename(staged.path, scene.path(staged.info.file), ec);
  FLAT_CHECK(!ec, staged.path + ": cannot move into place as " + scene.path(staged.info.file) + ": " + ec.message());
  put_latent_set(scene, staged.info);
  scene.latents = staged.info;
  write_scene_json(scene);
  if (!old_file.empty()) {
    bool still_named = false;
    for (const auto& set : scene.latent_sets) still_named |= set.file == old_file;
    if (!still_named) std::filesystem::remove(scene.path(old_file), ec);
  }
}

void discard_staged_latents(const StagedLatents& staged) {
  std::error_code ec;
  std::filesystem::remove(staged.path, ec);
}

int remove_stale_staged_latents(const Scene& scene) {
  int removed = 0;
  std::error_code ec;
  for (const auto& e : std::filesystem::directory_iterator(scene.dir, ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind("latents", 0) == 0 && name.find(".safetensors.staged-") != std::string::npos &&
        std::filesystem::remove(e.path(), ec))
      ++removed;
  }
  return removed;
}

void write_scene_latents(Scene& scene, LatentInfo info, const std::vector<WindowLatents>& latents) {
  commit_scene_latents(scene, stage_scene_latents(scene, std::move(info), latents));
}

namespace {
// Latents are floating point: an integer tensor is a wrong file, not values to convert.
at::Tensor read_latent(const safetensors::MappedFile& file, const std::string& key, const std::string& what) {
  auto t = read_tensor(file, key);
  if (t.defined() && !t.is_floating_point())
    fail(what + ": dtype " + std::string(c10::toString(t.scalar_type())) +
         "; latents must be floating point (float32, bfloat16 or float16)");
  return t.defined() ? t.to(at::kFloat) : t;
}
}  // namespace

WindowLatents read_window_latents(const Scene& scene, size_t window, const std::string& camera_rays) {
  const auto& info = scene.latents;
  FLAT_CHECK(info.present(), scene.json_path() + ": scene '" + scene.name + "' has " +
                                 (scene.latent_sets.empty() ? "no latents"
                                                            : "several latent sets (" + latent_set_list(scene) +
                                                                  ") and none was chosen"));
  FLAT_CHECK(window < info.windows.size(), scene.json_path() + ": latent window " + std::to_string(window) +
                                               " out of range (" + std::to_string(info.windows.size()) + ")");
  const std::string path = scene.path(info.file);
  auto file = safetensors::MappedFile::open(path);
  const std::string k = std::to_string(window);
  WindowLatents out;
  FLAT_CHECK(camera_rays == "rppc" || camera_rays == "plucker",
             "read_window_latents: camera_rays must be rppc or plucker, got '" + camera_rays + "'");
  FLAT_CHECK(camera_rays == "rppc" || info.plucker,
             scene.json_path() + ": scene '" + scene.name + "' has no Plucker camera latents (the model is "
             "conditioned on Plucker rays: flat_latents --camera-rays rppc,plucker writes them)");
  const std::string camera_key = (camera_rays == "plucker" ? "camera_plucker." : "camera.") + k;
  out.video = read_latent(*file, "video." + k, path + ": 'video." + k + "'");
  out.camera = read_latent(*file, camera_key, path + ": '" + camera_key + "'");
  check_window(out.video, 16, info, info.windows[window], path + ": 'video." + k + "'");
  check_window(out.camera, 32, info, info.windows[window], path + ": '" + camera_key + "'");
  auto frames = read_tensor(*file, "frames." + k);
  const auto& w = info.windows[window];
  if (frames.numel() != w.count || frames[0].item<int64_t>() != w.start)
    fail(path + ": 'frames." + k + "' does not match scene.json latents.windows[" + k + "]");
  return out;
}

}  // namespace flat::data
