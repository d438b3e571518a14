#include "flat/infer/mesh_run.h"

#include <chrono>
#include <filesystem>

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
#include "flat/data/scene.h"
#include "flat/export/mesh_files.h"
#include "flat/export/triangle_glb.h"
#include "flat/export/triangle_ply.h"
#include "flat/export/viewer.h"
#include "flat/mesh/mesh_statistics.h"
#include "flat/pipeline/scene_pipeline.h"
#include "infer/mesh_inputs.h"
#include "infer/stage_scores.h"

namespace fs = std::filesystem;

namespace flat::infer {

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

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

void check_options(const MeshRunOptions& o) {
  FLAT_CHECK(o.holdout_every >= 0, "--holdout-every must be >= 0");
  FLAT_CHECK(o.render_chunk > 0, "--render-chunk must be positive");
  if (o.viewer && !o.three_js_dir.empty() && !exporter::viewer_available(o.three_js_dir))
    fail("--three-js " + o.three_js_dir + ": three.js r111 not found there; give the right folder or --no-viewer");
}

// Refinement and conversion fit one objective; LPIPS weights add the
// perceptual term at the training objective's weight.
struct Objectives {
  mesh::RefineOptions refine;
  mesh::OpaqueOptions opaque;
};

Objectives objectives(const MeshRunOptions& o) {
  Objectives j{o.refine, o.opaque};
  if (!o.lpips_weights.empty()) {
    j.refine.loss.lpips_weights = o.lpips_weights;
    if (j.refine.loss.lambda_perc <= 0) j.refine.loss.lambda_perc = 0.5;
  }
  j.opaque.loss = j.refine.loss;
  j.refine.raster.check();
  return j;
}

loss::Lpips open_lpips(const std::string& weights, const at::Device& device, std::vector<std::string>& notes) {
  loss::Lpips lpips{nullptr};
  if (weights.empty()) {
    notes.push_back("no --lpips-weights: LPIPS is not scored and the objective is L2 only");
    return lpips;
  }
  lpips = loss::Lpips();
  lpips->load(weights);
  lpips->to(device);
  return lpips;
}

// refined.ply, and refined.glb where this build has tinygltf.
void write_refined(const StagedDir& out, const primitives::TriangleSoup& refined, bool glb, MeshRunSummary& s) {
  const primitives::TriangleSoup cpu{refined.vertices.cpu(), refined.colors.cpu(), refined.opacities.cpu(),
                                     refined.sigmas.cpu()};
  exporter::write_triangle_ply(out.file("refined.ply"), cpu);
  s.outputs.push_back("refined.ply");
  if (glb) {
    exporter::write_triangle_glb(out.file("refined.glb"), cpu);
    s.outputs.push_back("refined.glb");
  } else {
    s.notes.push_back("GLB files not written: this build has no tinygltf (Debian libtinygltf-dev)");
  }
}

// The opaque mesh, scored as the stage "mesh" and written with its
// statistics; returns mesh_stats.json's content.
nlohmann::json convert_and_write(const primitives::TriangleSoup& refined, const mesh::ViewTargets& fitted,
                                 const mesh::OpaqueOptions& options, const at::Device& device, bool glb,
                                 const StagedDir& out, StageScorer& scorer, mesh::ConversionReport& conversion,
                                 MeshRunSummary& s) {
  const auto t = Clock::now();
  const auto m = mesh::convert_to_opaque_mesh(refined, fitted, options, &conversion);
  s.convert_seconds = since(t);
  const auto drawn = mesh::opaque_render_soup(m, options);
  scorer.add("mesh",
             {drawn.vertices.to(device), drawn.colors.to(device), drawn.opacities.to(device), drawn.sigmas.to(device)},
             mesh::opaque_raster(options.raster), s);
  const auto stats = mesh::mesh_statistics(m);
  s.statistics = mesh::format_statistics(stats);
  spdlog::info("mesh: {}", s.statistics);
  const auto stats_json = mesh::to_json(stats);
  write_file_atomic(out.file("mesh_stats.json"), stats_json.dump(2) + "\n");
  exporter::write_mesh_ply(out.file("mesh.ply"), m);
  exporter::write_mesh_obj(out.file("mesh.obj"), m);
  s.outputs.insert(s.outputs.end(), {"mesh.ply", "mesh.obj", "mesh_stats.json"});
  if (glb) {
    exporter::write_mesh_glb(out.file("mesh.glb"), m);
    s.outputs.push_back("mesh.glb");
  }
  return stats_json;
}

// Two fitted and two held-out views side by side.
void write_comparison(const StagedDir& out, const mesh::ViewTargets& all, const ViewSplit& split,
                      const std::vector<Rendered>& stages, MeshRunSummary& s) {
  std::vector<int64_t> rows;
  for (const auto* part : {&split.fitted, &split.held_out})
    for (int64_t k = 0; k < std::min<int64_t>(2, part->numel()); ++k) rows.push_back((*part)[k].item<int64_t>());
  const auto grid = write_preview_image(comparison_grid(all, stages, rows), out.file("renders/compare"));
  s.outputs.push_back("renders/" + fs::path(grid).filename().string());
}

// The viewer shows the GLB files; a note says why it is missing otherwise.
void write_viewer(const MeshRunOptions& o, const StagedDir& out, const mesh::ViewTargets& all, bool glb,
                  MeshRunSummary& s) {
  if (!glb) {
    s.notes.push_back("viewer not written: it shows GLB files, which this build cannot write");
    return;
  }
  const std::string why_not = exporter::write_viewer_if_available(
      out.file("viewer"), out.file("refined.glb"), {all.cameras.to(at::kCPU), all.width(), all.height()},
      o.three_js_dir, o.convert ? out.file("mesh.glb") : "");
  if (why_not.empty()) s.outputs.push_back("viewer/index.html");
  else s.notes.push_back(why_not);
}

std::vector<int64_t> to_vector(const at::Tensor& indices) {
  return {indices.data_ptr<int64_t>(), indices.data_ptr<int64_t>() + indices.numel()};
}

void write_metrics(const StagedDir& out, const std::string& scene, int64_t window, const ViewSplit& split,
                   const nlohmann::json& stats_json, MeshRunSummary& s) {
  nlohmann::json scores;
  for (const auto& [stage, splits] : s.scores)
    for (const auto& [part, sc] : splits) scores[stage][part] = to_json(sc);
  const nlohmann::json views = {{"fitted", to_vector(split.fitted)}, {"held_out", to_vector(split.held_out)}};
  write_file_atomic(out.file("metrics.json"),
                    nlohmann::json{{"scene", scene}, {"window", window}, {"views", views},
                                   {"scores", scores}, {"mesh_statistics", stats_json}}
                            .dump(2) +
                        "\n");
  s.outputs.push_back("metrics.json");
}

nlohmann::json refine_json(const mesh::RefineReport& r, int64_t steps, double seconds) {
  return {{"steps", steps},
          {"triangles_before", r.triangles_before},
          {"triangles_after", r.triangles_after},
          {"first_loss", r.losses.empty() ? 0.0 : r.losses.front()},
          {"last_loss", r.losses.empty() ? 0.0 : r.losses.back()},
          {"seconds", seconds}};
}

nlohmann::json conversion_json(const mesh::ConversionReport& c, const std::string& method, double seconds) {
  return {{"method", method},
          {"soup_triangles", c.soup_triangles},
          {"grid_faces", c.grid_faces},
          {"fused_faces", c.fused_faces},
          {"welded_vertices", c.welded_vertices},
          {"unwelded_vertices", c.unwelded_vertices},
          {"weld_dropped_faces", c.weld_dropped_faces},
          {"after_selection", c.after_selection},
          {"after_support", c.after_support},
          {"stitched_pairs", c.stitched_pairs},
          {"collapsed_faces", c.collapsed_faces},
          {"densified_faces", c.densified_faces},
          {"floater_faces", c.floater_faces},
          {"mesh_vertices", c.mesh_vertices},
          {"mesh_faces", c.mesh_faces},
          {"seconds", seconds}};
}

}  // namespace

MeshRunSummary run_mesh(const MeshRunOptions& o) {
  const auto t_start = Clock::now();
  MeshRunSummary s;
  check_options(o);
  const auto objective = objectives(o);

  const auto source = read_mesh_source(o);
  auto scene = data::read_scene(source.scene_dir);
  data::choose_latent_set(scene, source.latent_set);
  StagedDir out(o.out_dir, o.overwrite);
  setup_logging(o.log_level, out.file("mesh.log"));
  spdlog::info("flat_mesh: {} triangles from {}; fitting scene {} window {}; writing into {} (appears when finished)",
               source.soup.vertices.size(0), o.from, scene.name, source.window, o.out_dir);
  s.scene = scene.name;
  const at::Device device = cli::resolve_device(o.device);

  const bool want_depth = objective.refine.loss.lambda_depth > 0 || objective.opaque.loss.lambda_depth > 0;
  const auto all = load_window_targets(scene, source.window, want_depth, scene.has_normals).to(device);
  const auto split = split_views(all.size(), o.holdout_every);
  const auto fitted = all.index(split.fitted);
  spdlog::info("views: {} of {}x{}, {} fitted, {} held out (every {}th)", all.size(), all.height(), all.width(),
               split.fitted.numel(), split.held_out.numel(), o.holdout_every);
  auto lpips = open_lpips(o.lpips_weights, device, s.notes);
  StageScorer scorer(all, split, lpips, load_baselines(o.baseline_scenes, scene, source, all), o.render_chunk);

  reset_peak_memory(device);
  const primitives::TriangleSoup start{source.soup.vertices.to(device), source.soup.colors.to(device),
                                       source.soup.opacities.to(device), source.soup.sigmas.to(device)};
  scorer.add("feedforward", start, objective.refine.raster, s);

  const auto t = Clock::now();
  mesh::RefineReport refine_report;
  const auto refined = refine_soup(start, fitted, objective.refine, &refine_report);
  s.refine_seconds = since(t);
  scorer.add("refined", refined, objective.refine.raster, s);
  const bool glb = exporter::glb_export_available();
  write_refined(out, refined, glb, s);

  nlohmann::json stats_json;
  mesh::ConversionReport conversion;
  if (o.convert)
    stats_json = convert_and_write(refined, fitted, objective.opaque, device, glb, out, scorer, conversion, s);
  s.peak_gib = peak_memory_gib(device);

  write_comparison(out, all, split, scorer.stages(), s);
  if (o.viewer) write_viewer(o, out, all, glb, s);
  write_metrics(out, scene.name, source.window, split, stats_json, s);
  for (const auto& n : s.notes) spdlog::warn("note: {}", n);
  s.total_seconds = since(t_start);
  s.out_dir = o.out_dir;
  s.outputs.insert(s.outputs.end(), {"summary.json", "mesh.log"});
  const nlohmann::json j = {{"from", o.from},
                            {"scene_dir", source.scene_dir},
                            {"window", source.window},
                            {"device", device.str()},
                            {"refine", refine_json(refine_report, objective.refine.steps, s.refine_seconds)},
                            {"conversion", conversion_json(conversion, objective.opaque.conversion, s.convert_seconds)},
                            {"seconds", s.total_seconds},
                            {"peak_memory_gib", s.peak_gib},
                            {"notes", s.notes},
                            {"outputs", s.outputs}};
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
