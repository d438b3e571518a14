// The benchmark behind flat_bench decoder: forward time and peak memory of the FLAT scene decoder
// (camera adapter + Wan decoder without the last x2 + triangle heads), bf16, at
// the paper's sizes: 13 latent frames of 54x96 (49 views at 432x768) and 21.
//
//   flat_bench decoder                       # 13 and 21 frames, full and streaming
//   flat_bench decoder --latent-frames 13 --mode full --camera encoded --breakdown
//
// Timing: median of --repeats runs after --warmup runs, each bracketed by
// device synchronisation. Memory: peak of the CUDA caching allocator during the
// timed runs (weights and inputs included).
#include "flat/bench/decoder_benchmark.h"

#include <algorithm>
#include <chrono>

#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/bench/timing.h"
#include "flat/camera/cameras.h"
#include "flat/core/cli.h"
#include "flat/core/device_memory.h"
#include "flat/core/error.h"
#include "flat/model/camera_latents.h"
#include "flat/model/conv3d_inference.h"
#include "flat/model/rms_norm.h"
#include "flat/model/scene_decoder.h"
#include "flat/model/wan_vae.h"
#include "flat/model/weights.h"

namespace flat::bench {
namespace {

using namespace flat::model;


void sync(const torch::Device& d) { sync_device(d); }

void reset_peak(const torch::Device& d) { reset_peak_memory(d); }

double peak_gib(const torch::Device& d) { return peak_memory_gib(d); }

camera::Cameras orbit(int64_t n) {
  camera::Cameras cams;
  cams.intrinsics = torch::tensor({0.8f, 1.4f, 0.5f, 0.5f}).repeat({n, 1});
  cams.c2w = torch::eye(4).repeat({n, 1, 1});
  for (int64_t i = 0; i < n; ++i) cams.c2w[i][0][3] = 0.02f * float(i);
  return cams;
}

// Mean ms of fn over 5 runs after one warm-up, synchronised.
template <class Fn>
double op_ms(const torch::Device& dev, Fn&& fn) {
  fn();
  sync(dev);
  const double t0 = now_ms();
  for (int i = 0; i < 5; ++i) fn();
  sync(dev);
  return (now_ms() - t0) / 5.0;
}

// The operations inside one residual block (its norm + SiLU, each conv, the
// residual add on its own for scale) and inside the heads, on real inputs.
void time_block_ops(const std::string& name, ResidualBlock& block, const at::Tensor& h, const torch::Device& dev) {
  const int64_t n1 = block->conv1->past_frames(), n2 = block->conv2->past_frames();
  const at::Tensor p1 = block->norm1->silu_padded(h, n1);
  const at::Tensor y1 = block->conv1->forward_prepadded(p1);
  const at::Tensor p2 = block->norm2->silu_padded(y1, n2);
  const at::Tensor skip = block->shortcut ? block->shortcut->forward(h) : h;
  const double norm1 = op_ms(dev, [&] { (void)block->norm1->silu_padded(h, n1); });
  const double conv1 = op_ms(dev, [&] { (void)block->conv1->forward_prepadded(p1); });
  const double norm2 = op_ms(dev, [&] { (void)block->norm2->silu_padded(y1, n2); });
  const double conv2 = op_ms(dev, [&] { (void)block->conv2->forward_prepadded(p2, skip); });
  const double add = op_ms(dev, [&] { (void)(y1 + skip); });
  const double gib = double(h.numel() * h.element_size()) / double(1ull << 30);
  spdlog::info("  {:<28} norm1 {:6.2f} conv1 {:6.2f} norm2 {:6.2f} conv2+skip {:6.2f} (a plain add: {:5.2f}) ms; "
               "input {:.2f} GiB",
               name, norm1, conv1, norm2, conv2, add, gib);
}

void time_head_ops(OutputHeads& heads, const at::Tensor& f, const torch::Device& dev) {
  for (size_t i = 0; i < heads->convs.size(); ++i) {
    const int64_t n = heads->convs[i]->past_frames();
    const at::Tensor p = heads->norms[i]->silu_padded(f, n);
    const double norm = op_ms(dev, [&] { (void)heads->norms[i]->silu_padded(f, n); });
    const double conv = op_ms(dev, [&] { (void)heads->convs[i]->forward_prepadded(p); });
    spdlog::info("  head {} ({} outputs): norm {:6.2f} conv {:6.2f} ms", i, heads->convs[i]->out_channels(), norm, conv);
  }
  spdlog::info("  heads, whole forward: {:6.2f} ms", op_ms(dev, [&] { (void)heads->forward(f); }));
}

// One forward timed stage by stage (synchronised, so slightly slower overall):
// the full sequence, or the streaming loop (the low-resolution trunk in steps
// of stream_trunk_frames latent frames, the rest one latent frame at a time,
// as SceneDecoder::forward) with each stage's time summed over the steps.
void run_breakdown(SceneDecoder& scene, const at::Tensor& latent, const at::Tensor& cams, const torch::Device& dev,
                   bool streaming, bool ops) {
  std::vector<std::pair<std::string, at::Tensor>> block_inputs;  // first block of each width and size
  std::vector<std::pair<std::string, double>> stages;  // first-seen order
  auto timed = [&](const std::string& name, auto&& fn) {
    sync(dev);
    const double t0 = now_ms();
    at::Tensor out = fn();
    sync(dev);
    const double ms = now_ms() - t0;
    auto it = std::find_if(stages.begin(), stages.end(), [&](const auto& st) { return st.first == name; });
    if (it == stages.end()) stages.emplace_back(name, ms);
    else it->second += ms;
    return out;
  };
  auto& d = scene->decoder;
  const size_t split = d->trunk_stages();
  // Stages [begin, end) of `upsamples` (r residual blocks and s resamples before begin).
  auto upsamples = [&](at::Tensor h, StreamCache* c, size_t begin, size_t end) {
    size_t r = 0, s = 0;
    for (size_t i = 0; i < begin; ++i) (d->up_kind[i] == 0 ? r : s)++;
    for (size_t i = begin; i < end; ++i) {
      const std::string name = "upsamples." + std::to_string(i) + (d->up_kind[i] == 0 ? " res " : " resample");
      if (d->up_kind[i] == 0) {
        const std::string what = std::to_string(h.size(1)) + "ch " + std::to_string(h.size(3)) + "x" +
                                 std::to_string(h.size(4));
        if (ops && c == nullptr) block_inputs.emplace_back("upsamples." + std::to_string(i) + " " + what, h);
        h = timed(name + what, [&] { return d->up_res[r++]->forward(h, c); });
      } else {
        h = timed(name, [&] { return d->up_resample[s++]->forward(h, c); });
      }
    }
    return h;
  };
  auto trunk = [&](const at::Tensor& l, const at::Tensor& cam, StreamCache* c) {
    at::Tensor z = timed("adapter + denormalise + conv2", [&] {
      at::Tensor x = cam.defined() ? l + scene->adapter->forward(cam, c) : l;
      x = scene->conv2->forward(denormalise_latent(x));
      return scene->channels_last_input(x);
    });
    at::Tensor h = timed("decoder.conv1", [&] { return c ? d->conv1->forward_cached(z, c->next()) : d->conv1->forward(z); });
    h = timed("middle (res, attn, res)",
              [&] { return d->mid2->forward(d->mid_attn->forward(d->mid1->forward(h, c)), c); });
    return upsamples(h, c, 0, split);
  };
  auto tail = [&](const at::Tensor& h, StreamCache* c) {
    const at::Tensor f = upsamples(h, c, split, d->up_kind.size());
    if (ops && c == nullptr) block_inputs.emplace_back("heads", f);
    return timed("heads", [&] { return scene->heads->forward(f, c); });
  };
  if (!streaming) {
    tail(trunk(latent, cams, nullptr), nullptr);
  } else {
    StreamCache trunk_cache, tail_cache;
    const int64_t T = latent.size(2), step = scene->config().stream_trunk_frames;
    for (int64_t i = 0; i < T; i += step) {
      const int64_t n = std::min(step, T - i);
      trunk_cache.begin_chunk();
      const at::Tensor h = trunk(latent.narrow(2, i, n), cams.defined() ? cams.narrow(2, i, n) : cams, &trunk_cache);
      int64_t frame = 0;
      for (int64_t j = i; j < i + n; ++j) {
        const int64_t frames = Decoder3dImpl::trunk_frames(j, split);
        tail_cache.begin_chunk();
        tail(h.narrow(2, frame, frames), &tail_cache);
        frame += frames;
      }
    }
  }
  double total = 0;
  for (auto& st : stages) total += st.second;
  spdlog::info("stages of one {} forward:", streaming ? "streaming" : "full-sequence");
  for (auto& st : stages) spdlog::info("  {:<45} {:8.2f} ms {:5.1f}%", st.first, st.second, 100.0 * st.second / total);
  spdlog::info("  {:<45} {:8.2f} ms", "sum of stages", total);
  if (block_inputs.empty()) return;
  spdlog::info("operations (mean of 5, synchronised):");
  std::vector<std::string> seen;
  for (auto& [name, input] : block_inputs) {
    if (name == "heads") {
      time_head_ops(scene->heads, input, dev);
      continue;
    }
    const size_t index = std::stoul(name.substr(10));  // "upsamples.<i> ..."
    const std::string what = name.substr(name.find(' ') + 1);
    if (std::find(seen.begin(), seen.end(), what) != seen.end()) continue;
    seen.push_back(what);
    size_t r = 0;
    for (size_t i = 0; i < index; ++i) r += d->up_kind[i] == 0 ? 1 : 0;
    time_block_ops(name, d->up_res[r], input, dev);
  }
}


}  // namespace

void run_decoder_benchmark(const DecoderBenchOptions& o) {
  const torch::Device dev = cli::resolve_device(o.device);
  const bool cuda = dev.is_cuda();
  const auto dtype = o.dtype == "bf16" ? torch::kBFloat16 : torch::kFloat;
  // cuDNN autotuning: the warm-up runs try the algorithms for every conv shape.
  at::globalContext().setBenchmarkCuDNN(o.cudnn_benchmark);
  torch::manual_seed(0);

  SceneDecoderConfig config;
  config.vae.dim = o.dim;
  config.heads = o.heads;
  config.stream_trunk_frames = o.stream_trunk_frames;
  // --fused-norm and --conv are the model config's kernel choices (model.kernels).
  config.kernels.fused_norm = o.fused_norm;
  config.kernels.conv_backend = o.conv;
  validate_kernels(config.kernels, "flat_bench decoder (--fused-norm, --conv)");
  SceneDecoder scene(config);
  scene->eval();
  scene->to(dev, dtype);
  if (o.channels_last) to_channels_last_3d(*scene);
  WanVAE vae{nullptr};
  if (o.camera == "encoded") {
    vae = WanVAE(config.vae, config.kernels);
    vae->eval();
    vae->to(dev, dtype);
    if (o.channels_last) to_channels_last_3d(*vae);
  }
  spdlog::info("scene decoder: {} parameters ({} heads), dim {}, {} on {}{}{}{}, convs: {}",
               count_parameters(*scene), o.heads, o.dim, o.dtype, cuda ? "cuda" : "cpu",
               o.channels_last ? ", channels-last 3D" : ", NCDHW", o.fused_norm ? ", fused norm" : ", ATen norm",
               o.cudnn_benchmark ? ", cuDNN benchmark" : "",
               o.conv == "auto" ? (cutlass_conv_compiled() ? "fastest of cuDNN and CUTLASS per shape" : "cuDNN")
                                : o.conv);
  c10::InferenceMode inference;
  std::vector<std::string> modes;
  if (o.mode == "both" || o.mode == "full") modes.push_back("full");
  if (o.mode == "both" || o.mode == "streaming") modes.push_back("streaming");

  for (int64_t t : o.frames) {
    const int64_t F = video_frames(t);
    // The inputs and the output of a forward must fit before anything is
    // allocated (a lower bound: the activations between come on top).
    const double elem = double(c10::elementSize(dtype)), hw = double(o.height) * double(o.width);
    const double latents = 48.0 * double(t) * hw * (sizeof(float) + elem);  // video + camera, drawn in fp32
    const double output = double(scene->channels().total) * double(F) * 16.0 * hw * elem;
    cli::check_memory(latents + output,
                      "flat_bench decoder: T'=" + std::to_string(t) + " latent frame(s) of " +
                          std::to_string(o.height) + "x" + std::to_string(o.width) + " (" + std::to_string(F) +
                          " view(s) of " + std::to_string(8 * o.height) + "x" + std::to_string(8 * o.width) +
                          "), inputs and output (1," + std::to_string(scene->channels().total) + "," +
                          std::to_string(F) + "," + std::to_string(4 * o.height) + "," + std::to_string(4 * o.width) +
                          ") in " + o.dtype,
                      dev);
    at::Tensor latent = torch::randn({1, 16, t, o.height, o.width}).to(dev, dtype);
    at::Tensor cam_pre = torch::randn({1, 32, t, o.height, o.width}).to(dev, dtype);
    camera::Cameras cams = orbit(F);
    for (const auto& mode : modes) {
      const bool streaming = mode == "streaming";
      auto once = [&] {
        at::Tensor c = o.camera == "encoded" ? encode_camera_latents(vae, cams, 8 * o.height, 8 * o.width, streaming)
                                             : cam_pre;
        return scene->forward(latent, c, streaming);
      };
      // Said before the first run, and after each run slower than 2 s: a CPU
      // run at the paper's size takes minutes, and must not be silent.
      const int total = o.warmup + o.repeats;
      spdlog::info("decoder T'={} ({} views {}x{}) mode={}: {} warm-up + {} timed run(s) on {}", t, F, 8 * o.height,
                   8 * o.width, mode, o.warmup, o.repeats, cuda ? "cuda" : "cpu");
      auto report_run = [&](int done, double ms) {
        if (ms >= 2000 && done < total)
          spdlog::info("  run {} of {} took {:.1f} s; about {:.0f} s to go for this configuration", done, total,
                       ms / 1000, ms / 1000 * (total - done));
      };
      for (int i = 0; i < o.warmup; ++i) {
        sync(dev);
        const double t0 = now_ms();
        once();
        sync(dev);
        report_run(i + 1, now_ms() - t0);
      }
      sync(dev);
      reset_peak(dev);
      std::vector<double> times;
      at::Tensor out;
      for (int i = 0; i < o.repeats; ++i) {
        sync(dev);
        const double t0 = now_ms();
        out = once();
        sync(dev);
        times.push_back(now_ms() - t0);
        report_run(o.warmup + i + 1, times.back());
      }
      std::sort(times.begin(), times.end());
      spdlog::info(
          "decoder T'={} ({} views {}x{}) mode={} camera={}: median {:.1f} ms (min {:.1f}, max {:.1f}, {} runs), "
          "peak {:.2f} GiB, output ({},{},{},{},{})",
          t, F, 8 * o.height, 8 * o.width, mode, o.camera, times[times.size() / 2], times.front(), times.back(),
          times.size(), peak_gib(dev), out.size(0), out.size(1), out.size(2), out.size(3), out.size(4));
    }
    if (o.breakdown) {
      spdlog::info("breakdown, T'={} (camera latents precomputed):", t);
      for (const auto& mode : modes) run_breakdown(scene, latent, cam_pre, dev, mode == "streaming", o.ops);
    }
  }
  const std::string report = cutlass_conv_report();
  if (!report.empty()) spdlog::info("conv shapes timed (candidate ms -> choice):\n{}", report);
}

}  // namespace flat::bench
