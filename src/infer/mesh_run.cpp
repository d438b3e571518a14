#include "flat/infer/mesh_run.h"

#include <chrono>
#include <filesystem>
#include <fstream>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/core/atomic_file.h"
#include "flat/core/cli.h"
#include "flat/core/device_memory.h"
#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/log.h"
#include "flat/core/staged_dir.h"
#include "flat/data/frame_resize.h"
#include "flat/data/scene.h"
#include "flat/data/scene_frames.h"
#include "flat/eval/baselines.h"
#include "flat/eval/image_metrics.h"
#include "flat/eval/normal_metrics.h"
#include "flat/export/mesh_files.h"
#include "flat/export/triangle_glb.h"
#include "flat/export/triangle_ply.h"
#include "flat/export/viewer.h"
#include "flat/mesh/mesh_statistics.h"
#include "flat/pipeline/scene_pipeline.h"

namespace fs = std::filesystem;

namespace flat::infer {

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

struct Source {
  primitives::TriangleSoup soup;
  std::string scene_dir;
  int64_t window = -1;
  std::string latent_set;  // "" = the scene's only set
};

// The soup, and the scene window it came from (flat_infer's summary.json).
Source read_source(const MeshRunOptions& o) {
  Source s;
  std::string ply = o.from;
  if (fs::is_directory(o.from)) {
    ply = o.from + "/scene.ply";
    FLAT_CHECK(fs::is_regular_file(ply), o.from + ": no scene.ply (expected a flat_infer output folder)");
    const std::string summary = o.from + "/summary.json";
    if (fs::is_regular_file(summary)) {
      nlohmann::json j;
      try {
        std::ifstream in(summary);
        j = nlohmann::json::parse(in);
      } catch (const std::exception& e) {
        fail(summary + ": not valid JSON: " + e.what());
      }
      if (j.contains("representation") && j["representation"] != "triangles")
        fail(o.from + ": holds a " + j["representation"].get<std::string>() +
             " scene; flat_mesh refines and meshes triangle scenes only");
      if (j.contains("scene_dir")) s.scene_dir = j["scene_dir"].get<std::string>();
      if (j.contains("window")) s.window = j["window"].get<int64_t>();
      if (j.contains("latent_set")) s.latent_set = j["latent_set"].get<std::string>();
    }
  }
  s.soup = exporter::read_triangle_ply(ply);
  FLAT_CHECK(s.soup.vertices.size(0) > 0, ply + ": the soup has no triangles");
  if (!o.scene_dir.empty()) s.scene_dir = o.scene_dir;
  if (o.window >= 0) s.window = o.window;
  if (!o.latent_set.empty()) s.latent_set = o.latent_set;
  FLAT_CHECK(!s.scene_dir.empty(), "--scene: which scene folder holds the frames to fit? (" + o.from +
                                       " does not name one: flat_infer records it only for scene-folder input)");
  if (s.window < 0) s.window = 0;
  return s;
}

// The window's frames at the soup's frame size (the latents' size).
mesh::ViewTargets load_targets(const data::Scene& scene, int64_t window, bool depth, bool normals) {
  FLAT_CHECK(scene.latents.present(), scene.json_path() + ": the scene has no latents, so no window to fit");
  FLAT_CHECK(window < int64_t(scene.latents.windows.size()),
             fmt::format("{}: window {} does not exist (the scene has {})", scene.json_path(), window,
                         scene.latents.windows.size()));
  const auto w = scene.latents.windows[size_t(window)];
  std::vector<int64_t> idx;
  for (int64_t i = 0; i < w.count; ++i) idx.push_back(w.start + i);
  FLAT_CHECK(!depth || scene.has_depth, scene.json_path() + ": the depth term needs depth maps, the scene has none");
  FLAT_CHECK(!normals || scene.has_normals, scene.json_path() + ": scoring normals needs normal maps");
  auto frames = data::load_frames(scene, idx, depth, normals);
  const int64_t H = scene.latents.height > 0 ? scene.latents.height : scene.height;
  const int64_t W = scene.latents.width > 0 ? scene.latents.width : scene.width;
  const auto cams = scene.cameras(idx);
  const auto intr = data::fit_frames(frames, cams.intrinsics, H, W);
  return {frames.images, frames.depth, frames.normals, camera::Cameras{intr, cams.c2w}};
}

struct Split {
  at::Tensor fitted, held_out;  // (K,) int64 view indices
};

Split split_views(int64_t views, int64_t every) {
  std::vector<int64_t> fit, held;
  for (int64_t i = 0; i < views; ++i) (every > 1 && i % every == every / 2 ? held : fit).push_back(i);
  FLAT_CHECK(!fit.empty(), "--holdout-every: no view left to fit");
  return {at::tensor(fit, at::kLong), at::tensor(held, at::kLong)};
}

struct Rendered {
  at::Tensor rgb, normal, alpha;  // CPU
};

Rendered render_all(const primitives::TriangleSoup& soup, const mesh::ViewTargets& t,
                    const render::RasterSettings& raster, int64_t chunk) {
  at::NoGradGuard no_grad;
  std::vector<at::Tensor> rgb, normal, alpha;
  for (int64_t s = 0; s < t.size(); s += chunk) {
    const auto views = at::arange(s, std::min(s + chunk, t.size()), at::kLong);
    const auto out = render::rasterize(soup.vertices, soup.colors, soup.opacities, soup.sigmas,
                                       t.cameras.index(views.to(t.cameras.c2w.device())), t.height(), t.width(),
                                       raster);
    const auto r = pipeline::normalise_by_alpha(out);
    rgb.push_back(r.rgb.cpu());
    normal.push_back(r.normal.cpu());
    alpha.push_back(r.alpha.cpu());
  }
  return {at::cat(rgb), at::cat(normal), at::cat(alpha)};
}

// Frames of other scenes for the baselines (undefined when none).
struct Baselines {
  at::Tensor dataset_mean;  // (V,3,H,W): the other scenes' frames averaged per view
  at::Tensor swap;          // (V,3,H,W): the first other scene's frames
};

ViewScores score(const Rendered& r, const mesh::ViewTargets& t, const at::Tensor& views, loss::Lpips& lpips,
                 int64_t triangles, const Baselines& b) {
  ViewScores s;
  s.views = views.numel();
  s.triangles = triangles;
  if (s.views == 0) return s;
  const auto rgb = r.rgb.index_select(0, views).clamp(0, 1);
  const auto gt = t.rgb.cpu().index_select(0, views);
  s.psnr = eval::psnr(rgb, gt).mean().item<double>();
  s.ssim = eval::ssim(rgb, gt).mean().item<double>();
  if (!lpips.is_empty()) s.lpips = eval::lpips(lpips, rgb, gt).mean().item<double>();
  s.mean_colour_psnr = eval::mean_colour_psnr(gt).mean().item<double>();
  if (b.swap.defined()) {
    s.dataset_mean_psnr = eval::psnr(b.dataset_mean.index_select(0, views), gt).mean().item<double>();
    s.swap_psnr = eval::psnr(rgb, b.swap.index_select(0, views)).mean().item<double>();
  }
  if (t.normals.defined()) {
    const auto acc = eval::normal_accuracy(r.normal.index_select(0, views), t.normals.cpu().index_select(0, views),
                                           r.alpha.index_select(0, views) > 0.5);
    s.normal_cosine = acc.mean_cosine;
  }
  return s;
}

nlohmann::json to_json(const ViewScores& s) {
  const auto num = [](double x) { return std::isfinite(x) ? nlohmann::json(x) : nlohmann::json(nullptr); };
  return {{"views", s.views},         {"triangles", s.triangles}, {"psnr", num(s.psnr)},
          {"ssim", num(s.ssim)},      {"lpips", num(s.lpips)},    {"normal_cosine", num(s.normal_cosine)},
          {"mean_colour_psnr", num(s.mean_colour_psnr)}, {"dataset_mean_psnr", num(s.dataset_mean_psnr)},
          {"swap_psnr", num(s.swap_psnr)}};
}

at::Tensor normal_picture(const at::Tensor& n) { return (n * 0.5 + 0.5).clamp(0, 1) * (n.norm(2, 1, true) > 0.5); }

// Rows of [ground truth | stage...] for the views `rows`, RGB above normals.
at::Tensor comparison_grid(const mesh::ViewTargets& t, const std::vector<Rendered>& stages,
                           const std::vector<int64_t>& rows) {
  std::vector<at::Tensor> out;
  const auto pad = [](const at::Tensor& x) { return at::constant_pad_nd(x, {0, 2, 0, 2}, 1.0); };
  for (int64_t v : rows) {
    std::vector<at::Tensor> rgb = {pad(t.rgb[v].cpu())}, nrm;
    nrm.push_back(pad(t.normals.defined() ? normal_picture(t.normals[v].cpu().unsqueeze(0))[0]
                                          : at::zeros_like(t.rgb[v].cpu())));
    for (const auto& s : stages) {
      rgb.push_back(pad(s.rgb[v].clamp(0, 1)));
      nrm.push_back(pad(normal_picture(s.normal[v].unsqueeze(0))[0]));
    }
    out.push_back(at::cat(rgb, 2));
    out.push_back(at::cat(nrm, 2));
  }
  return at::cat(out, 1);
}

void use_lpips(loss::LossConfig& c, const std::string& weights) {
  if (weights.empty()) return;
  c.lpips_weights = weights;
  if (c.lambda_perc <= 0) c.lambda_perc = 0.5;  // the training objective's weight
}

}  // namespace

MeshRunSummary run_mesh(const MeshRunOptions& o) {
  const auto t_start = Clock::now();
  MeshRunSummary s;
  FLAT_CHECK(o.holdout_every >= 0, "--holdout-every must be >= 0");
  FLAT_CHECK(o.render_chunk > 0, "--render-chunk must be positive");
  const std::string three = o.three_js_dir.empty() ? exporter::default_three_js_dir() : o.three_js_dir;
  if (o.viewer && !o.three_js_dir.empty() && !exporter::viewer_available(o.three_js_dir))
    fail("--three-js " + o.three_js_dir + ": three.js r111 not found there; give the right folder or --no-viewer");
  auto refine_options = o.refine;
  auto opaque_options = o.opaque;
  use_lpips(refine_options.loss, o.lpips_weights);
  opaque_options.loss = refine_options.loss;  // one objective for the whole run
  refine_options.raster.check();

  const auto source = read_source(o);
  auto scene = data::read_scene(source.scene_dir);
  data::choose_latent_set(scene, source.latent_set);
  StagedDir out(o.out_dir, o.overwrite);
  setup_logging(o.log_level, out.file("mesh.log"));
  spdlog::info("flat_mesh: {} triangles from {}; fitting scene {} window {}; writing into {} (appears when finished)",
               source.soup.vertices.size(0), o.from, scene.name, source.window, o.out_dir);
  s.scene = scene.name;
  const at::Device device = cli::resolve_device(o.device);

  const bool want_depth = refine_options.loss.lambda_depth > 0 || opaque_options.loss.lambda_depth > 0;
  const bool want_normals = scene.has_normals;
  const auto all = load_targets(scene, source.window, want_depth, want_normals).to(device);
  const auto split = split_views(all.size(), o.holdout_every);
  const auto fitted = all.index(split.fitted);
  spdlog::info("views: {} of {}x{}, {} fitted, {} held out (every {}th)", all.size(), all.height(), all.width(),
               split.fitted.numel(), split.held_out.numel(), o.holdout_every);

  loss::Lpips lpips{nullptr};
  if (!o.lpips_weights.empty()) {
    lpips = loss::Lpips();
    lpips->load(o.lpips_weights);
    lpips->to(device);
  } else {
    s.notes.push_back("no --lpips-weights: LPIPS is not scored and the objective is L2 only");
  }

  Baselines baselines;
  {
    std::vector<at::Tensor> others;
    for (const auto& dir : o.baseline_scenes) {
      auto other = data::read_scene(dir);
      data::choose_latent_set(other, source.latent_set);
      if (fs::equivalent(other.dir, scene.dir)) continue;
      auto t = load_targets(other, source.window, false, false);
      FLAT_CHECK(t.size() == all.size() && t.height() == all.height() && t.width() == all.width(),
                 fmt::format("--baseline-scenes {}: window {} has {} frames of {}x{}, this scene {} of {}x{}", dir,
                             source.window, t.size(), t.height(), t.width(), all.size(), all.height(), all.width()));
      others.push_back(t.rgb.cpu());
    }
    if (!others.empty()) {
      baselines.swap = others.front();
      baselines.dataset_mean = at::stack(others).mean(0);
      spdlog::info("baselines: {} other scenes (dataset mean); swap against {}", others.size(),
                   o.baseline_scenes.front());
    }
  }

  std::vector<Rendered> stages;
  const auto add_stage = [&](const std::string& name, const primitives::TriangleSoup& soup,
                             const render::RasterSettings& raster) {
    stages.push_back(render_all(soup, all, raster, o.render_chunk));
    const int64_t n = soup.vertices.size(0);
    s.scores[name]["fitted"] = score(stages.back(), all, split.fitted, lpips, n, baselines);
    s.scores[name]["held_out"] = score(stages.back(), all, split.held_out, lpips, n, baselines);
    const auto& f = s.scores[name]["fitted"];
    const auto& h = s.scores[name]["held_out"];
    spdlog::info("{}: {} triangles; fitted views PSNR {:.2f} dB (mean-colour oracle {:.2f}), normal cosine {:.3f}; "
                 "held-out views PSNR {:.2f} dB (oracle {:.2f}, dataset mean {:.2f}, swap {:.2f}), normal cosine {:.3f}",
                 name, n, f.psnr, f.mean_colour_psnr, f.normal_cosine, h.psnr, h.mean_colour_psnr,
                 h.dataset_mean_psnr, h.swap_psnr, h.normal_cosine);
  };

  reset_peak_memory(device);
  const primitives::TriangleSoup start{source.soup.vertices.to(device), source.soup.colors.to(device),
                                       source.soup.opacities.to(device), source.soup.sigmas.to(device)};
  add_stage("feedforward", start, refine_options.raster);

  auto t = Clock::now();
  mesh::RefineReport refine_report;
  const auto refined = refine_soup(start, fitted, refine_options, &refine_report);
  s.refine_seconds = since(t);
  add_stage("refined", refined, refine_options.raster);
  const primitives::TriangleSoup refined_cpu{refined.vertices.cpu(), refined.colors.cpu(), refined.opacities.cpu(),
                                             refined.sigmas.cpu()};
  exporter::write_triangle_ply(out.file("refined.ply"), refined_cpu);
  s.outputs.push_back("refined.ply");
  const bool glb = exporter::glb_export_available();
  if (glb) {
    exporter::write_triangle_glb(out.file("refined.glb"), refined_cpu);
    s.outputs.push_back("refined.glb");
  } else {
    s.notes.push_back("GLB files not written: this build has no tinygltf (Debian libtinygltf-dev)");
  }

  nlohmann::json stats_json;
  mesh::ConversionReport conversion;
  if (o.convert) {
    t = Clock::now();
    const auto m = mesh::convert_to_opaque_mesh(refined, fitted, opaque_options, &conversion);
    s.convert_seconds = since(t);
    const auto drawn = mesh::opaque_render_soup(m, opaque_options);
    add_stage("mesh",
              {drawn.vertices.to(device), drawn.colors.to(device), drawn.opacities.to(device), drawn.sigmas.to(device)},
              mesh::opaque_raster(opaque_options.raster));
    const auto stats = mesh::mesh_statistics(m);
    s.statistics = mesh::format_statistics(stats);
    spdlog::info("mesh: {}", s.statistics);
    stats_json = mesh::to_json(stats);
    write_file_atomic(out.file("mesh_stats.json"), stats_json.dump(2) + "\n");
    exporter::write_mesh_ply(out.file("mesh.ply"), m);
    exporter::write_mesh_obj(out.file("mesh.obj"), m);
    s.outputs.insert(s.outputs.end(), {"mesh.ply", "mesh.obj", "mesh_stats.json"});
    if (glb) {
      exporter::write_mesh_glb(out.file("mesh.glb"), m);
      s.outputs.push_back("mesh.glb");
    }
  }
  s.peak_gib = peak_memory_gib(device);

  // Two fitted and two held-out views side by side.
  std::vector<int64_t> rows;
  for (const auto* part : {&split.fitted, &split.held_out})
    for (int64_t k = 0; k < std::min<int64_t>(2, part->numel()); ++k) rows.push_back((*part)[k].item<int64_t>());
  const auto grid = write_preview_image(comparison_grid(all, stages, rows), out.file("renders/compare"));
  s.outputs.push_back("renders/" + fs::path(grid).filename().string());

  if (o.viewer) {
    if (!glb) {
      s.notes.push_back("viewer not written: it shows GLB files, which this build cannot write");
    } else if (!exporter::viewer_available(three)) {
      s.notes.push_back("viewer not written: three.js not found in " + three + " (Debian package libjs-three)");
    } else {
      exporter::write_viewer(out.file("viewer"), out.file("refined.glb"),
                             {all.cameras.to(at::kCPU), all.width(), all.height()}, three,
                             o.convert ? out.file("mesh.glb") : "");
      s.outputs.push_back("viewer/index.html");
    }
  }

  nlohmann::json scores;
  for (const auto& [stage, splits] : s.scores)
    for (const auto& [part, sc] : splits) scores[stage][part] = to_json(sc);
  nlohmann::json views = {{"fitted", std::vector<int64_t>(split.fitted.data_ptr<int64_t>(),
                                                          split.fitted.data_ptr<int64_t>() + split.fitted.numel())},
                          {"held_out", std::vector<int64_t>(split.held_out.data_ptr<int64_t>(),
                                                            split.held_out.data_ptr<int64_t>() +
                                                                split.held_out.numel())}};
  write_file_atomic(out.file("metrics.json"),
                    nlohmann::json{{"scene", scene.name}, {"window", source.window}, {"views", views},
                                   {"scores", scores}, {"mesh_statistics", stats_json}}
                            .dump(2) +
                        "\n");
  s.outputs.push_back("metrics.json");
  for (const auto& n : s.notes) spdlog::warn("note: {}", n);
  s.total_seconds = since(t_start);
  s.out_dir = o.out_dir;
  nlohmann::json j = {
      {"from", o.from},
      {"scene_dir", source.scene_dir},
      {"window", source.window},
      {"device", device.str()},
      {"refine", {{"steps", refine_options.steps},
                  {"triangles_before", refine_report.triangles_before},
                  {"triangles_after", refine_report.triangles_after},
                  {"first_loss", refine_report.losses.empty() ? 0.0 : refine_report.losses.front()},
                  {"last_loss", refine_report.losses.empty() ? 0.0 : refine_report.losses.back()},
                  {"seconds", s.refine_seconds}}},
      {"conversion", {{"method", opaque_options.conversion},
                      {"soup_triangles", conversion.soup_triangles},
                      {"grid_faces", conversion.grid_faces},
                      {"fused_faces", conversion.fused_faces},
                      {"after_selection", conversion.after_selection},
                      {"after_support", conversion.after_support},
                      {"stitched_pairs", conversion.stitched_pairs},
                      {"collapsed_faces", conversion.collapsed_faces},
                      {"densified_faces", conversion.densified_faces},
                      {"floater_faces", conversion.floater_faces},
                      {"mesh_vertices", conversion.mesh_vertices},
                      {"mesh_faces", conversion.mesh_faces},
                      {"seconds", s.convert_seconds}}},
      {"seconds", s.total_seconds},
      {"peak_memory_gib", s.peak_gib},
      {"notes", s.notes}};
  s.outputs.insert(s.outputs.end(), {"summary.json", "mesh.log"});
  j["outputs"] = s.outputs;
  write_file_atomic(out.file("summary.json"), j.dump(2) + "\n");
  setup_logging(o.log_level);  // close the log file before the folder moves
  out.commit();
  return s;
}

std::string format_summary(const MeshRunSummary& s) {
  std::string text = fmt::format("flat_mesh: done in {:.1f} s (refine {:.1f} s, conversion {:.1f} s) -> {}\n",
                                 s.total_seconds, s.refine_seconds, s.convert_seconds, s.out_dir);
  text += fmt::format("  {:<12} {:<9} {:>6} {:>9} {:>7} {:>7} {:>9} {:>8} {:>8} {:>8}\n", "stage", "views", "tris",
                      "PSNR", "SSIM", "LPIPS", "normals", "oracle", "mean", "swap");
  for (const char* stage : {"feedforward", "refined", "mesh"}) {
    auto it = s.scores.find(stage);
    if (it == s.scores.end()) continue;
    for (const char* part : {"fitted", "held_out"}) {
      const auto& v = it->second.at(part);
      if (v.views == 0) continue;
      text += fmt::format("  {:<12} {:<9} {:>6} {:>9.2f} {:>7.3f} {:>7.3f} {:>9.3f} {:>8.2f} {:>8.2f} {:>8.2f}\n", stage,
                          part, v.triangles, v.psnr, v.ssim, v.lpips, v.normal_cosine, v.mean_colour_psnr,
                          v.dataset_mean_psnr, v.swap_psnr);
    }
  }
  if (!s.statistics.empty()) text += "  mesh: " + s.statistics + "\n";
  for (const auto& n : s.notes) text += "  note: " + n + "\n";
  return text;
}

}  // namespace flat::infer
