// flat_mesh's job (paper: appendix "Post Optimization", Method "Opaque Mesh
// Conversion", appendix "Mesh Conversion Analysis"): take the soup that
// flat_infer decoded from a scene folder's latent window, refine it against
// that window's frames, convert it to an opaque mesh, score every stage and
// export:
//
//   <out>/refined.ply, refined.glb   the post-optimised soup
//   <out>/mesh.glb, mesh.ply, mesh.obj   the opaque mesh (export/mesh_files.h)
//   <out>/mesh_stats.json            mesh/mesh_statistics.h
//   <out>/metrics.json               PSNR / SSIM / LPIPS / normal cosine of the
//                                    feedforward soup, the refined soup and the
//                                    mesh, on the fitted and the held-out views,
//                                    beside the mean-colour oracle
//   <out>/renders/compare.(png|safetensors)  ground truth | feedforward |
//                                    refined | mesh, RGB and normals, per view
//   <out>/viewer/index.html          soup / mesh toggle (export/viewer.h)
//   <out>/summary.json, mesh.log
//
// Held-out views: every holdout_every-th frame of the window (from the
// middle of the first group on) is never fitted, so overfitting shows.
// The folder appears whole or not at all (core/staged_dir.h).
#pragma once
#include <cmath>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "flat/mesh/opaque_conversion.h"
#include "flat/mesh/refine.h"

namespace flat::infer {

struct MeshRunOptions {
  std::string from;           // a flat_infer output folder (scene.ply + summary.json), or a soup PLY
  std::string scene_dir;      // "" = the scene folder flat_infer's summary.json names
  int64_t window = -1;        // latent window of the scene (-1 = the summary's)
  std::string latent_set;     // latent set of the scene, HxW_fF ("" = the summary's, else the scene's only one)
  std::string out_dir;
  bool overwrite = false;
  std::string device = "auto";  // auto | cpu | cuda
  int64_t holdout_every = 4;    // 0 = fit every view (then nothing is held out)
  mesh::RefineOptions refine;
  bool convert = true;
  mesh::OpaqueOptions opaque;
  std::string lpips_weights;  // LPIPS metric, and the objective's perceptual term (0.5, as training); "" = neither
  // Other scene folders (same window index and frame count) for two baselines
  // a result must beat: the dataset mean (their frames averaged per view) and
  // the swap score (our renders against the first one's frames). Empty: none.
  std::vector<std::string> baseline_scenes;
  bool viewer = true;
  std::string three_js_dir;   // "" = Debian's libjs-three
  int64_t render_chunk = 8;
  std::string log_level = "info";
};

struct ViewScores {
  int64_t views = 0, triangles = 0;
  double psnr = NAN, ssim = NAN, lpips = NAN, normal_cosine = NAN, mean_colour_psnr = NAN;
  double dataset_mean_psnr = NAN, swap_psnr = NAN;  // with baseline_scenes
};

struct MeshRunSummary {
  std::string out_dir, scene;
  // stage ("feedforward" | "refined" | "mesh") -> split ("fitted" | "held_out") -> scores
  std::map<std::string, std::map<std::string, ViewScores>> scores;
  double refine_seconds = 0, convert_seconds = 0, total_seconds = 0, peak_gib = 0;
  std::vector<std::string> outputs, notes;
  std::string statistics;  // format_statistics() of the mesh, or ""
};

MeshRunSummary run_mesh(const MeshRunOptions& options);
std::string format_summary(const MeshRunSummary& summary);

}  // namespace flat::infer
