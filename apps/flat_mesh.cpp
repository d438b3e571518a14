// flat_mesh: post-optimise a decoded triangle soup against its frames and
// convert it into an opaque, connected mesh (src/infer/mesh_run.h lists the
// outputs; docs/inference.md, "Post-optimisation and mesh").
//
//   flat_infer --model runs/stage2 --scene data/val/room_000001 --out out/room1
//   flat_mesh --from out/room1 --out out/room1_mesh                # 250 refine steps, then the mesh
//   flat_mesh --from out/room1 --out out/room1_long --refine 2000 --no-mesh
//
// Exit codes: 0 done, 1 runtime error (message names the file, key or shape),
// 2 usage error.
#include <filesystem>
#include <iostream>

#include <CLI/CLI.hpp>

#include "flat/core/cli.h"
#include "flat/core/error.h"
#include "flat/core/log.h"
#include "flat/infer/mesh_run.h"

int main(int argc, char** argv) {
  CLI::App app{"flat_mesh: refine a decoded triangle soup against its frames and convert it to an opaque mesh "
               "(GLB, PLY, OBJ), with metrics and a viewer"};
  app.get_formatter()->column_width(36);
  flat::infer::MeshRunOptions o;
  flat::cli::add_common(app, "flat_mesh", o.log_level);
  bool no_mesh = false, no_viewer = false;
  app.add_option("--from", o.from, "flat_infer output folder (scene.ply + summary.json), or a soup .ply")->required();
  app.add_option("--scene", o.scene_dir, "scene folder whose frames are fitted (default: the one flat_infer used)");
  app.add_option("--window-index", o.window, "which stored latent window of --scene (default: flat_infer's)");
  flat::cli::add_old_name(app, "--window", "--window-index");
  app.add_option("--latent-set", o.latent_set, "latent set of --scene, HxW_fF (default: flat_infer's, else the scene's only one)");
  app.add_option("--out", o.out_dir,
                 "output folder (must not exist unless --overwrite); built in <out>.incomplete-<pid>, which a killed "
                 "run leaves and the next run on the same --out removes")
      ->required();
  app.add_flag("--overwrite", o.overwrite, "replace an existing output folder (only once the new one is complete)");
  flat::cli::add_device(app, o.device);
  int threads = 0;
  flat::cli::add_threads(app, threads);
  app.add_option("--refine", o.refine.steps, "post-optimisation steps (paper: 250; 0 = none)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--views-per-step", o.refine.views_per_step, "views rendered per refine step")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--holdout-every", o.holdout_every,
                 "hold out every Nth frame of the window (never fitted, scored apart; 0 = fit all)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--lr-position", o.refine.lr_position, "refine: position step, in triangle sizes")
      ->capture_default_str();
  app.add_option("--prune-opacity", o.refine.prune_opacity, "refine: prune below this opacity")->capture_default_str();
  app.add_option("--prune-weight", o.refine.prune_weight, "refine: prune below this largest blending weight")
      ->capture_default_str();
  app.add_option("--lambda-depth", o.refine.loss.lambda_depth,
                 "refine: weight of the depth term (needs the scene's depth maps; paper: 0, photometric only)")
      ->capture_default_str();
  app.add_option("--lambda-normal", o.refine.loss.lambda_normal,
                 "refine: weight of the normal term (needs the scene's normal maps; paper: 0)")
      ->capture_default_str();
  app.add_option("--lpips-weights", o.lpips_weights,
                 "LPIPS VGG weights (.safetensors): scored, and in the objective at 0.5 as in training");
  app.add_option("--baseline-scenes", o.baseline_scenes,
                 "other scene folders (same window): score the dataset-mean and swap baselines beside the results")
      ->take_all();
  bool no_seam_weld = false;
  app.add_flag("--no-mesh", no_mesh, "stop after the post-optimisation (no opaque conversion)");
  app.add_option("--conversion", o.opaque.conversion,
                 "mesh: grid (each view's depth grid, fused: faces share edges) | stitch (the paper's opacity "
                 "selection and boundary stitching)")
      ->check(CLI::IsMember({"grid", "stitch"}))
      ->capture_default_str();
  app.add_option("--grid-depth-weight", o.opaque.grid_depth_weight,
                 "mesh, grid: each view's depth re-solved from the refined soup's normals, with this pull towards its "
                 "rendered depth (0: the rendered depth as it is)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_flag("--no-seam-weld", no_seam_weld,
               "mesh, grid: append each view's faces beside the mesh so far instead of welding its seam onto it");
  app.add_option("--selection-steps", o.opaque.selection_steps, "mesh, stitch: opacity selection steps (paper: 50)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--repair-steps", o.opaque.repair_steps, "mesh: repair steps after stitching")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--support-min", o.opaque.support_min,
                 "mesh: remove triangles whose largest blending weight over every view is at or below this")
      ->capture_default_str();
  app.add_option("--stitch-distance", o.opaque.stitch_distance, "mesh, stitch: merge distance, in local edge lengths")
      ->capture_default_str();
  app.add_option("--min-component", o.opaque.min_component_faces, "mesh: remove pieces with fewer faces")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--render-chunk", o.render_chunk, "views per rasterizer call when scoring")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--three-js", o.three_js_dir, "three.js folder for the viewer (default: Debian's libjs-three)");
  app.add_flag("--no-viewer", no_viewer, "skip the browser viewer");
  if (int rc = flat::cli::parse(app, argc, argv); rc >= 0) return rc;
  flat::cli::apply_threads(threads);
  try {
    flat::setup_logging(o.log_level);
    o.convert = !no_mesh;
    o.opaque.fusion_weld = !no_seam_weld;
    o.viewer = !no_viewer;
    if (!std::filesystem::exists(o.from)) {
      std::cerr << "flat_mesh: --from " << o.from << ": no such file or folder\n";
      return 2;
    }
    auto summary = flat::infer::run_mesh(o);
    std::cout << flat::infer::format_summary(summary);
    return 0;
  } catch (...) {
    return flat::report_current_error();
  }
}
