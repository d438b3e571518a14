// flat_bench raster: forward and forward+backward time (median) and peak GPU
// memory of the triangle rasterizer, with each view's load (visible
// triangles, tile pairs, list entries per pixel) beside the times.
// Workloads (flat/bench/raster_workload.h): anchor-large and anchor-small, the
// benchmark of record (the triangles ../shared/bench/raster_workload.py gives
// the public Triangle Splatting rasterizer); paper and stage1, our older room
// scenes; or any PLY + cameras JSON. --device auto|cpu|cuda (peak memory and
// load are reported on CUDA only).
#include <memory>

#include <CLI/CLI.hpp>

#include "bench_registry.h"
#include "flat/bench/raster_benchmark.h"
#include "flat/core/cli.h"

namespace flat::bench {

void add_raster(CLI::App& app) {
  auto* sub = app.add_subcommand("raster", "rasterizers (triangles, 3DGS, 2DGS): forward, forward+backward time, peak memory and load");
  auto opts = std::make_shared<RasterBenchOptions>();
  sub->add_option("--workload", opts->workloads,
                  "anchor-large (4,064,256 triangles, 24 views 432x768) | anchor-small (783,360, 17 views 320x576): "
                  "the anchor's own triangles (../shared/bench/raster_workload.py); paper | stage1: our older room "
                  "scenes at the same sizes")
      ->check(CLI::IsMember({"anchor-large", "anchor-small", "paper", "stage1"}))
      ->capture_default_str();
  cli::add_device(*sub, opts->device);
  sub->add_option("--triangles", opts->ply, "time this triangle soup PLY instead (with --cameras)");
  sub->add_option("--cameras", opts->cams, "cameras JSON for --triangles");
  sub->add_option("--primitives", opts->representations,
                  "triangles | 3dgs | 2dgs (several: each timed on the same scene; the Gaussians are made from the "
                  "workload's triangles, one each, 1-sigma ellipse = incircle)")
      ->check(CLI::IsMember({"triangles", "3dgs", "2dgs"}))
      ->capture_default_str();
  cli::add_window_fn(*sub, opts->window);
  cli::add_old_name(*sub, "--window", "--window-fn");
  sub->add_option("--views-per-bin", opts->views_per_bin,
                  "views binned by one sort: 1 | 2 (the rasterizer's default)")
      ->check(CLI::Range(1, 2))
      ->capture_default_str();
  sub->add_option("--repeats", opts->repeats, "timed repeats after 2 warm-ups")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  sub->add_option("--seed", opts->seed, "anchor workloads: generator seed (the Python file's --seed)")
      ->capture_default_str();
  sub->add_option("--write-workload", opts->write_dir,
                  "write each generated workload as DIR/<name>.ply and DIR/<name>_cameras.json, then time it");
  sub->add_flag("--profile", opts->profile, "also print GPU time per kernel of one forward+backward step of each --primitives");
  sub->callback([opts] { run_raster_benchmark(*opts); });
}

}  // namespace flat::bench
