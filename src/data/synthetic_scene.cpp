#include "flat/data/synthetic_scene.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <exception>
#include <filesystem>
#include <mutex>
#include <thread>
#include <vector>

#include "flat/camera/rays.h"
#include "flat/core/error.h"
#include "flat/data/frame_io.h"
#include "data/synthetic/camera_path.h"
#include "data/synthetic/shapes.h"

namespace flat::data {

void SynthOptions::check() const {
  if (family != "room" && family != "object") fail("synthetic scene: family must be room or object, got '" + family + "'");
  if (motion != "pan" && motion != "zoom" && motion != "orbit" && motion != "mixed")
    fail("synthetic scene: motion must be pan, zoom, orbit or mixed, got '" + motion + "'");
  FLAT_CHECK(frames >= 1 && frames <= 1000, "synthetic scene: frames must be in [1, 1000], got " + std::to_string(frames));
  FLAT_CHECK(frames_per_batch >= 0,
             "synthetic scene: frames_per_batch must be >= 0 (0: automatic), got " + std::to_string(frames_per_batch));
  FLAT_CHECK(height >= 2 && width >= 2 && height <= 4096 && width <= 4096,
             "synthetic scene: size must be within 2..4096, got " + std::to_string(height) + "x" + std::to_string(width));
}

SynthScene render_synthetic_scene(const SynthOptions& o) {
  o.check();
  synth::Random rng(o.seed);
  const bool room = o.family == "room";
  synth::Layout layout = room ? synth::make_room(rng) : synth::make_object_scene(rng);
  synth::Path path = synth::make_path(layout, room, o.motion, o.frames, rng);

  // Square pixels: fx/W from the horizontal field of view, fy/H follows.
  const double fxn = 0.5 / std::tan(path.hfov / 2), fyn = fxn * double(o.width) / double(o.height);
  auto intr = at::tensor({fxn, fyn, 0.5, 0.5}, at::kDouble).to(at::kFloat).expand({o.frames, 4}).contiguous();
  std::vector<at::Tensor> mats;
  for (const auto& m : path.c2w) mats.push_back(at::tensor(std::vector<double>(m.begin(), m.end()), at::kDouble).view({4, 4}));
  camera::Cameras cams{intr, at::stack(mats).to(at::kFloat)};
  const camera::Cameras cams_on_device{intr.to(o.device), cams.c2w.to(o.device)};

  auto light = at::tensor({layout.light[0], layout.light[1], layout.light[2]}, at::kFloat).to(o.device);
  light = light / light.norm();
  // On the CPU, frames in parallel, each on one plain thread
  // (SynthOptions::frame_threads): coarse tasks instead of intra-op threads
  // over one frame's small tensors. The output does not depend on the threads.
  std::vector<at::Tensor> rgb(o.frames), depth(o.frames), normals(o.frames), surface(o.frames);
  std::mutex progress_mutex;
  // Frames [first, first + count) in one batch of rays: one frame per call on
  // the CPU's threads, many per call on a GPU (its kernels need large batches).
  auto render_frames = [&](int64_t first, int64_t count) {
    auto sel = cams_on_device.index(at::arange(first, first + count, at::TensorOptions(at::kLong).device(o.device)));
    camera::Rays rays = camera::pixel_rays(sel, o.height, o.width);
    auto org = rays.origins.reshape({-1, 3}), dir = rays.directions.reshape({-1, 3});
    synth::Hits hit = synth::cast_rays(layout, org, dir);
    auto valid = at::isfinite(hit.t);
    auto R = sel.c2w.narrow(1, 0, 3).narrow(2, 0, 3);  // (K,3,3) camera -> world rotations
    auto per_frame = [&](const at::Tensor& t) { return t.reshape({count, o.height * o.width, -1}); };
    // z-depth = distance along the ray times the cosine to the optical axis.
    auto cosine = (per_frame(dir) * R.select(2, 2).unsqueeze(1)).sum(-1).reshape({-1});
    auto z = at::where(valid, hit.t * cosine, at::zeros_like(hit.t));
    // Normals facing the camera (the side of the surface the ray sees).
    auto n = hit.normal * at::where((hit.normal * dir).sum(-1, true) > 0, -1.0, 1.0);
    auto n_cam = at::bmm(per_frame(n), R).reshape({-1, 3});  // R^T n for row vectors
    // Unit length to float precision (sphere normals (p - c)/r carry the hit point's rounding).
    n_cam = n_cam / n_cam.norm(2, -1, true).clamp_min(1e-12) * valid.unsqueeze(-1);
    auto shade = 0.35 + 0.65 * at::clamp_min(at::matmul(n, light), 0).unsqueeze(-1);
    auto colour = at::clamp(hit.albedo * shade, 0, 1) * valid.unsqueeze(-1);
    auto to_chw = [&](const at::Tensor& t, int64_t c) {
      return t.reshape({count, o.height, o.width, c}).permute({0, 3, 1, 2}).to(at::kCPU);
    };
    auto c = to_chw(colour, 3), d = to_chw(z.unsqueeze(-1), 1), nm = to_chw(n_cam, 3);
    auto id = hit.id.reshape({count, o.height, o.width}).to(at::kCPU);
    for (int64_t k = 0; k < count; ++k) {
      rgb[first + k] = c[k];
      depth[first + k] = d[k];
      normals[first + k] = nm[k];
      surface[first + k] = id[k];
      if (o.on_frame) {
        std::lock_guard<std::mutex> lock(progress_mutex);
        o.on_frame();
      }
    }
  };
  // A batch: one frame on the CPU (the threads take the frames), up to 4 M rays
  // on a GPU (a few hundred MB of temporaries), or SynthOptions::frames_per_batch.
  const int64_t per_batch =
      o.frames_per_batch > 0
          ? o.frames_per_batch
          : (o.device.is_cuda() ? std::max<int64_t>(1, (int64_t(1) << 22) / (o.height * o.width)) : 1);
  const int64_t batches = (o.frames + per_batch - 1) / per_batch;
  // A GPU takes its batches one after another: it is busy enough with one.
  const int64_t threads =
      o.device.is_cuda()
          ? 1
          : std::min<int64_t>(o.frame_threads > 0 ? o.frame_threads : std::max(1u, std::thread::hardware_concurrency()),
                              batches);
  std::atomic<int64_t> next{0};
  std::exception_ptr error;
  std::mutex error_mutex;
  auto worker = [&] {
    for (int64_t b = next++; b < batches; b = next++) {
      try {
        render_frames(b * per_batch, std::min(per_batch, o.frames - b * per_batch));
      } catch (...) {
        std::lock_guard<std::mutex> lock(error_mutex);
        if (!error) error = std::current_exception();
        next = batches;  // the others stop after their batch
      }
    }
  };
  std::vector<std::thread> pool;
  for (int64_t t = 1; t < threads; ++t) pool.emplace_back(worker);
  worker();
  for (auto& t : pool) t.join();
  if (error) std::rethrow_exception(error);
  SynthScene s;
  s.cameras = cams;
  s.images = at::stack(rgb).contiguous();
  s.depth = at::stack(depth).contiguous();
  s.normals = at::stack(normals).contiguous();
  s.surface = at::stack(surface).contiguous();
  s.planar = at::ones({layout.surface_count}, at::kBool);
  for (const auto& sp : layout.spheres) s.planar[sp.id] = false;
  s.motion = path.motion;
  return s;
}

Scene write_synthetic_scene(const SynthScene& s, const std::string& dir, const std::string& name,
                            const std::string& source) {
  namespace fs = std::filesystem;
  Scene scene;
  scene.dir = dir;
  scene.name = name;
  scene.source = source;
  scene.height = s.images.size(2);
  scene.width = s.images.size(3);
  scene.has_depth = scene.has_normals = true;
  const std::string rgb_ext = rgb_extension(), map_ext = float_map_extension();
  for (const char* sub : {"images", "depth", "normals"}) fs::create_directories(fs::path(dir) / sub);
  for (int64_t i = 0; i < s.images.size(0); ++i) {
    SceneFrame f;
    f.intrinsics = s.cameras.intrinsics[i].contiguous();
    f.c2w = s.cameras.c2w[i].contiguous();
    f.image = "images/" + frame_stem(i) + rgb_ext;
    f.depth = "depth/" + frame_stem(i) + map_ext;
    f.normals = "normals/" + frame_stem(i) + map_ext;
    write_rgb(scene.path(f.image), s.images[i]);
    write_depth(scene.path(f.depth), s.depth[i]);
    write_normals(scene.path(f.normals), s.normals[i]);
    scene.frames.push_back(std::move(f));
  }
  write_scene_json(scene);
  return scene;
}

}  // namespace flat::data
