#include "flat/infer/inference.h"

#include <chrono>
#include <filesystem>
#include <optional>
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

// ---- the run -------------------------------------------------------------------
// One call of run_inference, section by section: run_inference calls these
// in the order they are declared. What one section leaves for the next is a
// member. A failure at any point removes the staging folder (StagedDir).
class Inference {
 public:
  explicit Inference(const InferOptions& o) : o_(o) {}

  // The checks that need no file, the staging folder and its log, the device.
  void start();
  // The input window, the trained model's pipeline on the device, and the
  // novel trajectory when it is a cameras file.
  void load_model_and_input();
  // The scene of the window, its NaN check, then the pruning.
  void decode();
  // scene.ply, scene.glb, cameras/.
  void export_scene();
  // The input and novel trajectories: renders/ and videos/.
  void render();
  // viewer/ over scene.glb.
  void write_viewer();
  // summary.json; the folder appears.
  InferSummary finish();

 private:
  void export_cameras();
  void render_novel(const primitives::ScenePrimitives& on_device, const TrajectoryRenders& input, bool video);
  nlohmann::json summary_json() const;

  const InferOptions& o_;
  const Clock::time_point t_start_ = Clock::now();
  InferSummary s_;
  std::optional<StagedDir> out_;  // appears on finish(), removed on failure
  at::Device device_{at::kCPU};
  bool bf16_ = false;
  pipeline::TrainedModel trained_;
  InferInput input_;
  int64_t H_ = 0, W_ = 0;  // the render size
  camera::Cameras novel_;
  bool novel_file_ = false;  // the novel trajectory comes from a cameras file
  std::optional<pipeline::ScenePipeline> pipe_;
  primitives::ScenePrimitives scene_;  // pruned, on the CPU
  bool have_glb_ = false;
};

void Inference::start() {
  // Everything that can be checked before any work is. A viewer asked for by
  // naming its three.js folder is a promise: a wrong folder fails here, not
  // as a note at the end.
  if (o_.viewer && !o_.three_js_dir.empty() && !exporter::viewer_available(o_.three_js_dir))
    fail("--three-js " + o_.three_js_dir + ": three.js r111 not found there (needs three.min.js, "
         "examples/js/controls/OrbitControls.js and examples/js/loaders/GLTFLoader.js); give the right folder, leave "
         "--three-js out (Debian's libjs-three), or pass --no-viewer");
  out_.emplace(o_.out_dir, o_.overwrite);
  setup_logging(o_.log_level, out_->file("infer.log"));
  spdlog::info("flat_infer: writing into {} (appears when finished)", o_.out_dir);

  device_ = choose_device(o_.device);
  FLAT_CHECK(o_.precision == "fp32" || o_.precision == "bf16",
             "--precision: expected fp32 or bf16, got '" + o_.precision + "'");
  bf16_ = device_.is_cuda() && o_.precision == "bf16";  // the CPU computes in fp32
  FLAT_CHECK(o_.prune_opacity < 1, "--prune-opacity must be in [0, 1) (or negative: the model's own)");
}

void Inference::load_model_and_input() {
  trained_ = pipeline::load_trained_model(o_.model, o_.config, o_.overrides);
  spdlog::info("model: {} (pipeline config from {})", trained_.describe(), trained_.config_source);
  auto spec = o_.input;
  spec.need_camera_latents = trained_.config.model.camera;
  spec.camera_rays = trained_.config.model.camera_rays;
  input_ = load_infer_input(spec);
  if (input_.latent_encoder == "random")
    s_.notes.push_back("RANDOM-ENCODER LATENTS: the input latents come from a random-weight encoder and carry almost "
                       "nothing of the scene; this output is a pipeline check, not a result");
  const int64_t T = input_.cameras.size();
  H_ = o_.height > 0 ? o_.height : input_.height;
  W_ = o_.width > 0 ? o_.width : input_.width;
  spdlog::info("input: {}: {} latent frames -> {} frames of {}x{}", input_.label, input_.input.video_latents.size(2),
               T, input_.height, input_.width);

  // Novel trajectory: a preset around the first input camera, or a cameras file.
  novel_file_ = o_.novel.preset != "orbit" && o_.novel.preset != "dolly" && o_.novel.preset != "none";
  if (novel_file_) novel_ = camera::read_cameras_json(o_.novel.preset).cameras;

  // A model trained with pruning renders as it was trained: triangles under
  // its threshold never received a gradient (stage 4's 0.4).
  s_.prune_opacity = o_.prune_opacity >= 0 ? o_.prune_opacity
                     : trained_.config.prune_opacity > 0 ? trained_.config.prune_opacity
                                                         : kDefaultPruneOpacity;
  auto config = trained_.config;
  config.prune_opacity = s_.prune_opacity;
  trained_.decoder->to(device_);
  pipe_.emplace(config, trained_.decoder);
}

void Inference::decode() {
  reset_peak_memory(device_);
  const auto t = Clock::now();
  // Streaming moves each latent frame's triangles to the CPU as they are built,
  // so the GPU holds only the decoder's working set, whatever the length.
  primitives::ScenePrimitives all;
  {
    AutocastScope autocast(bf16_, at::kCUDA);
    if (o_.streaming) {
      all = pipe_->decode_to(input_.input, at::kCPU).scene(0);
    } else {
      all = pipe_->decode(input_.input, false).scene(0).map([](const at::Tensor& x) { return x.to(at::kCPU, at::kFloat); });
    }
  }
  if (device_.is_cuda()) torch::cuda::synchronize();
  s_.decode_seconds = since(t);
  s_.decode_peak_gib = peak_memory_gib(device_);
  s_.representation = all.representation;
  s_.triangles_decoded = all.size();
  for (const auto& [name, x] : all.named_tensors())
    FLAT_CHECK(at::isfinite(x).all().item<bool>(), input_.label + ": the decoded " + all.representation +
                                                       " hold NaN or infinite " + name + " (bad latents or weights)");
  scene_ = pipeline::prune(all, s_.prune_opacity);
  s_.triangles_kept = scene_.size();
  const std::string what = scene_.is_triangles() ? "triangles" : scene_.representation + " Gaussians";
  spdlog::info("decode: {} {} in {:.2f} s ({}), {} kept at opacity >= {}", s_.triangles_decoded, what,
               s_.decode_seconds, o_.streaming ? "streaming" : "full sequence", s_.triangles_kept, s_.prune_opacity);
  if (s_.triangles_kept == 0) spdlog::warn("no primitive reaches opacity {}: the exports are empty", s_.prune_opacity);
}

void Inference::export_scene() {
  const auto t = Clock::now();
  // Gaussians: scene.ply in the 3DGS ecosystem's layout; the GLB (and so the
  // viewer) shows them as ellipse fans (primitives/splat_ellipses.h).
  const auto cpu_scene =
      scene_.is_triangles() ? export_view(scene_.triangles) : primitives::splat_ellipses(scene_.gaussians);
  if (o_.ply) {
    if (scene_.is_triangles()) exporter::write_triangle_ply(out_->file("scene.ply"), cpu_scene);
    else exporter::write_gaussian_ply(out_->file("scene.ply"), scene_.gaussians);
    s_.outputs.push_back("scene.ply");
  }
  if (o_.glb) {
    if (exporter::glb_export_available()) {
      exporter::write_triangle_glb(out_->file("scene.glb"), cpu_scene);
      have_glb_ = true;
      s_.outputs.push_back("scene.glb");
    } else {
      s_.notes.push_back("GLB not written: this build has no tinygltf (Debian libtinygltf-dev)");
    }
  }
  export_cameras();
  s_.export_seconds = since(t);
}

// cameras/input.json, and cameras/novel.json unless the preset is "none".
void Inference::export_cameras() {
  camera::write_cameras_json(out_->file("cameras/input.json"), {input_.cameras, W_, H_});
  s_.outputs.push_back("cameras/");
  if (o_.novel.preset == "none") return;
  if (!novel_file_) {
    // Looking at the scene's middle depth as the first input camera sees it.
    const camera::Cameras first{input_.cameras.intrinsics.slice(0, 0, 1), input_.cameras.c2w.slice(0, 0, 1)};
    const auto range = display_depth_range(scene_, first);
    novel_ = camera::make_trajectory(input_.cameras, 0.5 * (range.first + range.second), o_.novel);
  }
  camera::write_cameras_json(out_->file("cameras/novel.json"), {novel_, W_, H_});
}

void Inference::render() {
  const auto t = Clock::now();
  reset_peak_memory(device_);
  const auto on_device = scene_.map([&](const at::Tensor& x) { return x.to(device_); });
  const bool video = o_.video && exporter::ffmpeg_available();
  if (o_.video && !video) s_.notes.push_back("videos not written: ffmpeg is not on the PATH (Debian package ffmpeg)");
  if (o_.renders || video) {
    const auto range = display_depth_range(scene_, input_.cameras);
    auto r = render_trajectory(*pipe_, on_device, input_.cameras, H_, W_, o_.renders ? out_->file("renders/input") : "",
                               o_.render_chunk, video, range, "render input views");
    s_.input_views = r.views;
    s_.input_uncovered = r.uncovered;
    s_.input_depth_range = r.depth_range;
    if (o_.renders) s_.outputs.push_back("renders/");
    if (video) s_.outputs.push_back("videos/");
    if (video) write_video(r, out_->file("videos/input.mp4"), o_.fps);
    if (novel_.intrinsics.defined()) render_novel(on_device, r, video);
  }
  s_.render_seconds = since(t);
  s_.render_peak_gib = peak_memory_gib(device_);
}

// Its own depth scale: the novel views may come closer than any input view.
void Inference::render_novel(const primitives::ScenePrimitives& on_device, const TrajectoryRenders& input,
                             bool video) {
  auto n = render_trajectory(*pipe_, on_device, novel_, H_, W_, o_.renders ? out_->file("renders/novel") : "",
                             o_.render_chunk, video, display_depth_range(scene_, novel_), "render novel views");
  s_.novel_views = n.views;
  s_.novel_uncovered = n.uncovered;
  s_.novel_depth_range = n.depth_range;
  // Novel views that look where no input frame did show black there: say so.
  if (n.uncovered > input.uncovered + 0.01)
    s_.notes.push_back(fmt::format("novel views leave {:.1f}% of their pixels uncovered (input views: {:.1f}%): the "
                                   "trajectory looks where the input frames did not{}",
                                   100 * n.uncovered, 100 * input.uncovered,
                                   o_.novel.preset == "orbit" ? "; a smaller --orbit-degrees stays inside" : ""));
  if (video) write_video(n, out_->file("videos/novel.mp4"), o_.fps);
}

void Inference::write_viewer() {
  if (!o_.viewer) return;
  if (!have_glb_) {
    s_.notes.push_back("viewer not written: it shows scene.glb, which was not written");
    return;
  }
  const std::string why_not = exporter::write_viewer_if_available(out_->file("viewer"), out_->file("scene.glb"),
                                                                  {input_.cameras, W_, H_}, o_.three_js_dir);
  if (why_not.empty()) s_.outputs.push_back("viewer/index.html");
  else s_.notes.push_back(why_not);
}

InferSummary Inference::finish() {
  for (const auto& n : s_.notes) spdlog::warn("note: {}", n);
  s_.total_seconds = since(t_start_);
  s_.out_dir = o_.out_dir;
  s_.outputs.push_back("summary.json");
  s_.outputs.push_back("infer.log");
  write_file_atomic(out_->file("summary.json"), summary_json().dump(2) + "\n");
  setup_logging(o_.log_level);  // close the log file before the folder moves
  out_->commit();
  return s_;
}

nlohmann::json Inference::summary_json() const {
  const InferSummary& s = s_;
  nlohmann::json j = {{"model", trained_.describe()},
                      {"input", input_.label},
                      {"latent_encoder", input_.latent_encoder},
                      {"device", device_.str()},
                      {"precision", bf16_ ? "bf16" : "fp32"},
                      {"streaming", o_.streaming},
                      {"representation", s.representation},
                      {"prune_opacity", s_.prune_opacity},
                      {"triangles_decoded", s.triangles_decoded},
                      {"triangles_kept", s.triangles_kept},
                      {"input_views", s.input_views},
                      {"novel_views", s.novel_views},
                      {"novel_trajectory", o_.novel.preset},
                      {"uncovered_pixels", {{"input", s.input_uncovered}, {"novel", s.novel_uncovered}}},
                      {"depth_display_range_m",
                       {{"input", {s.input_depth_range.first, s.input_depth_range.second}},
                        {"novel", {s.novel_depth_range.first, s.novel_depth_range.second}}}},
                      {"render_size", {H_, W_}},
                      {"seconds", {{"decode", s.decode_seconds}, {"export", s.export_seconds},
                                   {"render", s.render_seconds}, {"total", s.total_seconds}}},
                      {"peak_memory_gib", {{"decode", s.decode_peak_gib}, {"render", s.render_peak_gib}}},
                      {"notes", s.notes}};
  // Where the frames of this window are, for flat_mesh (refinement needs them).
  if (!o_.input.scene_dir.empty()) {
    j["scene_dir"] = std::filesystem::absolute(o_.input.scene_dir).string();
    j["window"] = o_.input.window;
    if (!o_.input.latent_set.empty()) j["latent_set"] = o_.input.latent_set;
  }
  j["outputs"] = s.outputs;
  return j;
}

}  // namespace

InferSummary run_inference(const InferOptions& o) {
  Inference run(o);
  run.start();
  run.load_model_and_input();
  torch::NoGradGuard no_grad;
  run.decode();
  run.export_scene();
  run.render();
  run.write_viewer();
  return run.finish();
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
