// The tiny runs of flat_train that the trainer's tests share: scenes made
// once per test process by flat_synth and flat_latents, a tiny CPU config,
// and readers of a run's metrics.
#pragma once
#include <fstream>
#include <string>
#include <tuple>
#include <vector>

#include <nlohmann/json.hpp>

#include "data/data_test_dirs.h"
#include "support/process.h"
#include "test_support.h"

namespace flat::test {

// Two training rooms and one held-out room, 9 frames of 32x48, latents of a
// random dim-4 encoder over windows of 5 frames, RPPC and Plucker camera
// latents (the conditioning ablation). Made once per test process.
inline const std::string& tiny_data() {
  static std::string dir = [] {
    const std::string d = fresh_dir("train_data").string();
    const std::string log = d + "/make.log";
    for (auto [name, scenes, seed] : {std::tuple{"train", "2", "3"}, std::tuple{"val", "1", "99"}}) {
      const std::string out = d + "/" + name;
      REQUIRE(run({binary("flat_synth"), "--out", out, "--count", scenes, "--seed", seed, "--family", "room",
                   "--frames", "9", "--size", "32x48", "--motion", "mixed"},
                  log) == 0);
      REQUIRE(run({binary("flat_latents"), "--scenes", out, "--random-weights", "--seed", "0", "--dim", "4",
                   "--window", "5", "--step", "4", "--camera-rays", "rppc,plucker"},
                  log) == 0);
    }
    return d;
  }();
  return dir;
}

// The head of every tiny CPU config: the run folder under `dir`, the
// `stage` lines, fp32 on one thread, a constant LR, a checkpoint every 2
// steps, progress every second and a dim-4 VAE (tiny_data()'s latents).
inline std::string tiny_run_yaml(const std::string& dir, const std::string& stage, int steps) {
  return "run_dir: " + dir + "/run\n" + stage + "\nsteps: " + std::to_string(steps) +
         "\ndevice: cpu\nprecision: fp32\nseed: 0\nthreads: 1\n" +
         "optim: {lr: 0.003, warmup_steps: 0, schedule: constant, weight_decay: 0}\n" +
         "checkpoint: {every: 2, keep: 2}\nlog: {progress_seconds: 1}\npipeline: {model: {vae: {dim: 4}}}\n";
}

// A tiny CPU config in `dir`/config.yaml; `extra` is appended (YAML keys at
// the top level override nothing: use --set for overrides).
inline std::string write_config(const std::string& dir, int steps, const std::string& extra = "") {
  const std::string& data = tiny_data();
  const std::string path = dir + "/config.yaml";
  std::ofstream(path) << tiny_run_yaml(dir, "stage: tiny", steps)
                      << "validation: {datasets: [{root: " << data << "/val}], every: 4, scenes: 1, grid_views: 2}\n"
                      << "data: {datasets: [{root: " << data << "/train}], height: 32, width: 48, input_frames: 5, "
                      << "target_views: 2, workers: 1, latents: true}\n"
                      << "loss: {lambda_perc: 0}\n"
                      << extra;
  return path;
}

inline std::vector<nlohmann::json> rows(const std::string& run_dir, const std::string& stream = "train") {
  std::vector<nlohmann::json> out;
  std::ifstream in(run_dir + "/metrics/" + stream + ".jsonl");
  for (std::string line; std::getline(in, line);)
    if (!line.empty()) out.push_back(nlohmann::json::parse(line));
  return out;
}

// The losses of a run as exact text (nlohmann prints doubles round-trip exactly).
inline std::vector<std::string> losses(const std::string& run_dir) {
  std::vector<std::string> out;
  for (const auto& r : rows(run_dir)) out.push_back(r.at("loss").dump());
  return out;
}

// The mean of `key` over the rows [from, from + count) of a run's metrics.
inline double mean_over(const std::vector<nlohmann::json>& r, const char* key, size_t from, size_t count) {
  double sum = 0;
  for (size_t i = from; i < from + count; ++i) sum += r.at(i).at(key).get<double>();
  return sum / double(count);
}

// The run learned: its mean `key` loss over the last 5 steps is below 0.6
// times its mean over the first 5.
inline void check_loss_fell(const std::vector<nlohmann::json>& r, const char* key) {
  REQUIRE(r.size() >= 10);
  const double first = mean_over(r, key, 0, 5), last = mean_over(r, key, r.size() - 5, 5);
  INFO("mean " << key << " loss, first 5 steps " << first << ", last 5 " << last);
  CHECK(last < 0.6 * first);
}

inline int train(const std::vector<std::string>& args, const std::string& log, const std::vector<std::string>& env = {}) {
  std::vector<std::string> argv = {binary("flat_train")};
  argv.insert(argv.end(), args.begin(), args.end());
  return run(argv, log, env);
}

}  // namespace flat::test
