#include "flat/infer/inference.h"

#include <chrono>
#include <filesystem>
#include <sstream>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/camera/camera_json.h"
#include "flat/core/atomic_file.h"
#include "flat/core/autocast_scope.h"
#include "flat/core/device_memory.h"
#include "flat/core/error.h"
#include "flat/core/log.h"
#include "flat/core/staged_dir.h"
#include "flat/export/gaussian_ply.h"
#include "flat/export/triangle_glb.h"
#include "flat/export/triangle_ply.h"
#include "flat/export/video_writer.h"
#include "flat/export/viewer.h"
#include "flat/infer/trajectory_renders.h"
#include "flat/pipeline/trained_model.h"
#include "flat/primitives/splat_ellipses.h"

namespace flat::infer {

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

at::Device choose_device(const std::string& name) {
  FLAT_CHECK(name == "auto" || name == "cpu" || name == "cuda", "--device: expected auto, cpu or cuda, got '" + name + "'");
  if (name == "cuda") FLAT_CHECK(torch::cuda::is_available(), "--device cuda: no CUDA device is available");
  if (name == "cpu" || (name == "auto" && !torch::cuda::is_available())) return at::kCPU;
  return at::Device(at::kCUDA, 0);
}

// RGB colours for export: the DC term when the model predicts SH coefficients.
primitives::TriangleSoup export_view(const primitives::TriangleSoup& s) {
  auto out = s;
  if (s.colors.dim() == 3) out.colors = (0.5 + 0.28209479177387814 * s.colors.select(1, 0)).clamp(0, 1);
  return out;
}

void write_video(const TrajectoryRenders& r, const std::string& path, double fps) {
  if (!r.video_frames.defined()) return;
  exporter::write_mp4(path, r.video_frames.to(at::kFloat).div_(255.0), fps);
}

}  // namespace

InferSummary run_inference(const InferOptions& o) {
  const auto t_start = Clock::now();
  InferSummary s;
  // Everything that can be checked before any work is. A viewer asked for by
  // naming its three.js folder is a promise: a wrong folder fails here, not
  // as a note at the end.
  if (o.viewer && !o.three_js_dir.empty() && !exporter::viewer_available(o.three_js_dir))
    fail("--three-js " + o.three_js_dir + ": three.js r111 not found there (needs three.min.js, "
         "examples/js/controls/OrbitControls.js and examples/js/loaders/GLTFLoader.js); give the right folder, leave "
         "--three-js out (Debian's libjs-three), or pass --no-viewer");
  StagedDir out(o.out_dir, o.overwrite);
  setup_logging(o.log_level, out.file("infer.log"));
  spdlog::info("flat_infer: writing into {} (appears when finished)", o.out_dir);

  const at::Device device = choose_device(o.device);
  FLAT_CHECK(o.precision == "fp32" || o.precision == "bf16",
             "--precision: expected fp32 or bf16, got '" + o.precision + "'");
  const bool bf16 = device.is_cuda() && o.precision == "bf16";  // the CPU computes in fp32
  FLAT_CHECK(o.prune_opacity >= 0 && o.prune_opacity < 1, "--prune-opacity must be in [0, 1)");

  auto trained = pipeline::load_trained_model(o.model, o.config, o.overrides);
  spdlog::info("model: {} (pipeline config from {})", trained.describe(), trained.config_source);
  auto spec = o.input;
  spec.need_camera_latents = trained.config.model.camera;
  spec.camera_rays = trained.config.model.camera_rays;
  auto input = load_infer_input(spec);
  if (input.latent_encoder == "random")
    s.notes.push_back("RANDOM-ENCODER LATENTS: the input latents come from a random-weight encoder and carry almost "
                      "nothing of the scene; this output is a pipeline check, not a result");
  const int64_t T = input.cameras.size();
  const int64_t H = o.height > 0 ? o.height : input.height, W = o.width > 0 ? o.width : input.width;
  spdlog::info("input: {}: {} latent frames -> {} frames of {}x{}", input.label, input.input.video_latents.size(2), T,
               input.height, input.width);

  // Novel trajectory: a preset around the first input camera, or a cameras file.
  camera::Cameras novel;
  const bool novel_file = o.novel.preset != "orbit" && o.novel.preset != "dolly" && o.novel.preset != "none";
  if (novel_file) novel = camera::read_cameras_json(o.novel.preset).cameras;

  auto config = trained.config;
  config.prune_opacity = o.prune_opacity;
  trained.decoder->to(device);
  pipeline::ScenePipeline pipe(config, trained.decoder);
  torch::NoGradGuard no_grad;

  // ---- decode ----------------------------------------------------------------------
  reset_peak_memory(device);
  auto t = Clock::now();
  // Streaming moves each latent frame's triangles to the CPU as they are built,
  // so the GPU holds only the decoder's working set, whatever the length.
  primitives::ScenePrimitives all;
  {
    AutocastScope autocast(bf16, at::kCUDA);
    if (o.streaming) {
      all = pipe.decode_to(input.input, at::kCPU).scene(0);
    } else {
      all = pipe.decode(input.input, false).scene(0).map([](const at::Tensor& x) { return x.to(at::kCPU, at::kFloat); });
    }
  }
  if (device.is_cuda()) torch::cuda::synchronize();
  s.decode_seconds = since(t);
  s.decode_peak_gib = peak_memory_gib(device);
  s.representation = all.representation;
  s.triangles_decoded = all.size();
  for (const auto& [name, x] : all.named_tensors())
    FLAT_CHECK(at::isfinite(x).all().item<bool>(), input.label + ": the decoded " + all.representation +
                                                       " hold NaN or infinite " + name + " (bad latents or weights)");
  auto scene = pipeline::prune(all, o.prune_opacity);
  s.prune_opacity = o.prune_opacity;
  s.triangles_kept = scene.size();
  const std::string what = scene.is_triangles() ? "triangles" : scene.representation + " Gaussians";
  spdlog::info("decode: {} {} in {:.2f} s ({}), {} kept at opacity >= {}", s.triangles_decoded, what,
               s.decode_seconds, o.streaming ? "streaming" : "full sequence", s.triangles_kept, o.prune_opacity);
  if (s.triangles_kept == 0) spdlog::warn("no primitive reaches opacity {}: the exports are empty", o.prune_opacity);

  // ---- export ----------------------------------------------------------------------
  t = Clock::now();
  // Gaussians: scene.ply in the 3DGS ecosystem's layout; the GLB (and so the
  // viewer) shows them as ellipse fans (primitives/splat_ellipses.h).
  const auto cpu_scene =
      scene.is_triangles() ? export_view(scene.triangles) : primitives::splat_ellipses(scene.gaussians);
  if (o.ply) {
    if (scene.is_triangles()) exporter::write_triangle_ply(out.file("scene.ply"), cpu_scene);
    else exporter::write_gaussian_ply(out.file("scene.ply"), scene.gaussians);
    s.outputs.push_back("scene.ply");
  }
  bool have_glb = false;
  if (o.glb) {
    if (exporter::glb_export_available()) {
      exporter::write_triangle_glb(out.file("scene.glb"), cpu_scene);
      have_glb = true;
      s.outputs.push_back("scene.glb");
    } else {
      s.notes.push_back("GLB not written: this build has no tinygltf (Debian libtinygltf-dev)");
    }
  }
  camera::write_cameras_json(out.file("cameras/input.json"), {input.cameras, W, H});
  s.outputs.push_back("cameras/");
  if (o.novel.preset != "none") {
    if (!novel_file) {
      // Looking at the scene's middle depth as the first input camera sees it.
      const camera::Cameras first{input.cameras.intrinsics.slice(0, 0, 1), input.cameras.c2w.slice(0, 0, 1)};
      const auto range = display_depth_range(scene, first);
      novel = camera::make_trajectory(input.cameras, 0.5 * (range.first + range.second), o.novel);
    }
    camera::write_cameras_json(out.file("cameras/novel.json"), {novel, W, H});
  }
  s.export_seconds = since(t);

  // ---- render ----------------------------------------------------------------------
  t = Clock::now();
  reset_peak_memory(device);
  const auto on_device = scene.map([&](const at::Tensor& x) { return x.to(device); });
  const bool video = o.video && exporter::ffmpeg_available();
  if (o.video && !video) s.notes.push_back("videos not written: ffmpeg is not on the PATH (Debian package ffmpeg)");
  if (o.renders || video) {
    const auto range = display_depth_range(scene, input.cameras);
    auto r = render_trajectory(pipe, on_device, input.cameras, H, W, o.renders ? out.file("renders/input") : "",
                               o.render_chunk, video, range, "render input views");
    s.input_views = r.views;
    s.input_uncovered = r.uncovered;
    s.input_depth_range = r.depth_range;
    if (o.renders) s.outputs.push_back("renders/");
    if (video) s.outputs.push_back("videos/");
    if (video) write_video(r, out.file("videos/input.mp4"), o.fps);
    if (novel.intrinsics.defined()) {
      // Its own depth scale: the novel views may come closer than any input view.
      auto n = render_trajectory(pipe, on_device, novel, H, W, o.renders ? out.file("renders/novel") : "", o.render_chunk,
                                 video, display_depth_range(scene, novel), "render novel views");
      s.novel_views = n.views;
      s.novel_uncovered = n.uncovered;
      s.novel_depth_range = n.depth_range;
      // Novel views that look where no input frame did show black there: say so.
      if (n.uncovered > r.uncovered + 0.01)
        s.notes.push_back(fmt::format("novel views leave {:.1f}% of their pixels uncovered (input views: {:.1f}%): the "
                                      "trajectory looks where the input frames did not{}",
                                      100 * n.uncovered, 100 * r.uncovered,
                                      o.novel.preset == "orbit" ? "; a smaller --orbit-degrees stays inside" : ""));
      if (video) write_video(n, out.file("videos/novel.mp4"), o.fps);
    }
  }
  s.render_seconds = since(t);
  s.render_peak_gib = peak_memory_gib(device);

  // ---- viewer ----------------------------------------------------------------------
  if (o.viewer) {
    const std::string three = o.three_js_dir.empty() ? exporter::default_three_js_dir() : o.three_js_dir;
    if (!have_glb) {
      s.notes.push_back("viewer not written: it shows scene.glb, which was not written");
    } else if (!exporter::viewer_available(three)) {
      s.notes.push_back("viewer not written: three.js not found in " + three + " (Debian package libjs-three)");
    } else {
      exporter::write_viewer(out.file("viewer"), out.file("scene.glb"), {input.cameras, W, H}, three);
      s.outputs.push_back("viewer/index.html");
    }
  }
  for (const auto& n : s.notes) spdlog::warn("note: {}", n);

  s.total_seconds = since(t_start);
  s.out_dir = o.out_dir;
  nlohmann::json j = {{"model", trained.describe()},
                      {"input", input.label},
                      {"latent_encoder", input.latent_encoder},
                      {"device", device.str()},
                      {"precision", bf16 ? "bf16" : "fp32"},
                      {"streaming", o.streaming},
                      {"representation", s.representation},
                      {"prune_opacity", o.prune_opacity},
                      {"triangles_decoded", s.triangles_decoded},
                      {"triangles_kept", s.triangles_kept},
                      {"input_views", s.input_views},
                      {"novel_views", s.novel_views},
                      {"novel_trajectory", o.novel.preset},
                      {"uncovered_pixels", {{"input", s.input_uncovered}, {"novel", s.novel_uncovered}}},
                      {"depth_display_range_m",
                       {{"input", {s.input_depth_range.first, s.input_depth_range.second}},
                        {"novel", {s.novel_depth_range.first, s.novel_depth_range.second}}}},
                      {"render_size", {H, W}},
                      {"seconds", {{"decode", s.decode_seconds}, {"export", s.export_seconds},
                                   {"render", s.render_seconds}, {"total", s.total_seconds}}},
                      {"peak_memory_gib", {{"decode", s.decode_peak_gib}, {"render", s.render_peak_gib}}},
                      {"notes", s.notes}};
  // Where the frames of this window are, for flat_mesh (refinement needs them).
  if (!o.input.scene_dir.empty()) {
    j["scene_dir"] = std::filesystem::absolute(o.input.scene_dir).string();
    j["window"] = o.input.window;
    if (!o.input.latent_set.empty()) j["latent_set"] = o.input.latent_set;
  }
  s.outputs.push_back("summary.json");
  s.outputs.push_back("infer.log");
  j["outputs"] = s.outputs;
  write_file_atomic(out.file("summary.json"), j.dump(2) + "\n");
  setup_logging(o.log_level);  // close the log file before the folder moves
  out.commit();
  return s;
}

std::string format_summary(const InferSummary& s) {
  std::ostringstream os;
  const double kept = s.triangles_decoded ? 100.0 * double(s.triangles_kept) / double(s.triangles_decoded) : 0.0;
  os << fmt::format("flat_infer: done in {:.1f} s -> {}\n", s.total_seconds, s.out_dir);
  os << fmt::format("  {:<10} {} decoded, {} kept ({:.1f}%, opacity >= {})\n",
                    s.representation == "triangles" ? "triangles" : s.representation, s.triangles_decoded,
                    s.triangles_kept, kept, s.prune_opacity);
  os << fmt::format("  decode     {:.2f} s{}\n", s.decode_seconds,
                    s.decode_peak_gib > 0 ? fmt::format("  (peak {:.2f} GiB)", s.decode_peak_gib) : "");
  os << fmt::format("  export     {:.2f} s\n", s.export_seconds);
  os << fmt::format("  render     {:.2f} s  {} input + {} novel views{}\n", s.render_seconds, s.input_views,
                    s.novel_views, s.render_peak_gib > 0 ? fmt::format("  (peak {:.2f} GiB)", s.render_peak_gib) : "");
  std::string files;
  for (const auto& f : s.outputs) files += (files.empty() ? "" : ", ") + f;
  os << "  outputs    " << files << "\n";
  for (const auto& n : s.notes) os << "  note       " << n << "\n";
  return os.str();
}

}  // namespace flat::infer
