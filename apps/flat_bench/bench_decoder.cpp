// flat_bench decoder: forward time and peak memory of the FLAT scene decoder
// (camera adapter + Wan decoder without the last x2 + triangle heads), bf16, at
// the paper's sizes: 13 latent frames of 54x96 (49 views at 432x768) and 21.
//
//   flat_bench decoder                       # 13 and 21 frames, full and streaming
//   flat_bench decoder --latent-frames 13 --mode full --camera encoded --breakdown
//
// Timing: median of --repeats runs after --warmup runs, each bracketed by
// device synchronisation. Memory: peak of the CUDA caching allocator during the
// timed runs (weights and inputs included).
#include <memory>

#include <CLI/CLI.hpp>

#include "bench_registry.h"
#include "flat/bench/decoder_benchmark.h"
#include "flat/core/cli.h"

namespace flat::bench {

void add_decoder(CLI::App& app) {
  auto opts = std::make_shared<DecoderBenchOptions>();
  auto* cmd = app.add_subcommand("decoder", "FLAT scene decoder (camera adapter + Wan decoder + heads) forward");
  cmd->add_option("--latent-frames", opts->frames, "latent frame counts (13 = 49 views, 21 = 81)")->capture_default_str();
  cmd->add_option("--height", opts->height, "latent height (54 = 432 px)")->capture_default_str();
  cmd->add_option("--width", opts->width, "latent width (96 = 768 px)")->capture_default_str();
  cmd->add_option("--mode", opts->mode, "full, streaming or both")
      ->check(CLI::IsMember({"full", "streaming", "both"}))
      ->capture_default_str();
  cmd->add_option("--camera", opts->camera, "precomputed camera latents, or encoded (RPPC + VAE encoder) each run")
      ->check(CLI::IsMember({"precomputed", "encoded"}))
      ->capture_default_str();
  cmd->add_option("--heads", opts->heads, "independent or monolithic")
      ->check(CLI::IsMember({"independent", "monolithic"}))
      ->capture_default_str();
  cmd->add_option("--stream-trunk-frames", opts->stream_trunk_frames,
                  "streaming: latent frames per step of the low-resolution trunk")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  cli::add_precision(*cmd, opts->dtype);
  cli::add_old_name(*cmd, "--dtype", "--precision");
  cli::add_device(*cmd, opts->device);
  cmd->add_option("--dim", opts->dim, "decoder base width (96 = paper)")->capture_default_str();
  cmd->add_option("--repeats", opts->repeats, "timed runs")->capture_default_str();
  cmd->add_option("--warmup", opts->warmup, "untimed runs first")->capture_default_str();
  cmd->add_option("--channels-last", opts->channels_last, "channels-last 3D layout (true/false)")->capture_default_str();
  cmd->add_option("--fused-norm", opts->fused_norm, "fused CUDA RMS_norm+SiLU kernel (true/false)")->capture_default_str();
  cmd->add_option("--cudnn-benchmark", opts->cudnn_benchmark, "cuDNN autotuning (true/false)")->capture_default_str();
  cmd->add_option("--conv", opts->conv,
                  "bf16 convs on sm_90: auto (fastest of cuDNN and CUTLASS, timed per shape), cudnn, or one CUTLASS "
                  "tile configuration (e.g. 128x192x64)")
      ->capture_default_str();
  cmd->add_flag("--breakdown", opts->breakdown, "also time each stage of a forward (each --mode)");
  cmd->add_flag("--ops", opts->ops,
                "with --breakdown: also time the norm, convs and add inside one residual block of each width and "
                "size, and each head");
  cmd->callback([opts] { run_decoder_benchmark(*opts); });
}

}  // namespace flat::bench
