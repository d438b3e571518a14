// flat_bench loader: training-loader throughput at a stage's sizes (default
// stage 1: 17 input frames, 17 targets, 320p = 176x320), on synthetic scenes
// written to a temporary folder (or --data DIR), from frame files (PNG/EXR)
// and from packed scenes (frames.safetensors).
//
//   flat_bench loader                                   # stage 1, files and packed
//   flat_bench loader --window 49 --targets 49 --scene-frames 81   # stage 2
//   flat_bench loader --storage packed --count 8
//   flat_bench loader --data /data/re10k --workers 8
//
// Reports batches/s and samples/s over --batches batches after --warmup.
#include <memory>

#include <CLI/CLI.hpp>

#include "bench_registry.h"
#include "flat/bench/loader_benchmark.h"
#include "flat/core/cli.h"

namespace flat::bench {

void add_loader(CLI::App& app) {
  auto o = std::make_shared<LoaderBenchOptions>();
  auto* sub = app.add_subcommand("loader", "training loader throughput (synthetic scenes, files vs packed)");
  sub->add_option("--data", o->data, "dataset folder to read (default: synthesise into a temp folder)");
  sub->add_option("--count", o->scenes, "number of synthetic scenes")->capture_default_str();
  cli::add_old_name(*sub, "--scenes", "--count");
  sub->add_option("--scene-frames", o->scene_frames, "frames per synthetic scene")->capture_default_str();
  sub->add_option("--source-size", o->source_size, "synthetic frame size HxW")->capture_default_str();
  sub->add_option("--size", o->size, "loader output size HxW (stage 1: 320p)")->capture_default_str();
  sub->add_option("--window", o->frames, "input window F (frames)")->capture_default_str();
  sub->add_option("--targets", o->targets, "target views V")->capture_default_str();
  sub->add_option("--batch", o->batch, "scenes per batch")->capture_default_str();
  sub->add_option("--workers", o->workers, "prefetch threads")->capture_default_str();
  sub->add_option("--prefetch", o->prefetch, "batches loaded ahead")->capture_default_str();
  sub->add_option("--batches", o->batches, "timed batches")->capture_default_str();
  sub->add_option("--warmup", o->warmup, "untimed batches first")->capture_default_str();
  sub->add_option("--storage", o->mode, "read frames from files (PNG/EXR), packed (frames.safetensors) or both")
      ->check(CLI::IsMember({"files", "packed", "both"}))
      ->capture_default_str();
  cli::add_old_name(*sub, "--mode", "--storage");
  sub->callback([o] { run_loader_benchmark(*o); });
}

}  // namespace flat::bench
