#include "flat/eval/evaluation_run.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "flat/core/exception_text.h"
#include "flat/core/log.h"
#include "flat/core/progress.h"
#include "flat/data/scene.h"
#include "flat/pipeline/trained_model.h"

namespace flat::eval {
namespace fs = std::filesystem;

namespace {

struct SceneRef {
  std::string dataset, dir;
};

// "NAME=PATH" | "PATH" -> the scene folders, labelled.
std::vector<SceneRef> collect_scenes(const std::vector<std::string>& specs) {
  FLAT_CHECK(!specs.empty(), "no datasets given (--scenes NAME=FOLDER)");
  std::vector<SceneRef> out;
  for (const auto& spec : specs) {
    const auto eq = spec.find('=');
    std::string name = eq == std::string::npos ? "" : spec.substr(0, eq);
    const std::string path = eq == std::string::npos ? spec : spec.substr(eq + 1);
    std::error_code ec;
    if (name.empty()) name = fs::path(path).filename().string();
    if (name.empty()) name = fs::path(path).parent_path().filename().string();
    FLAT_CHECK(name.find_first_of("/\\") == std::string::npos, spec + ": a dataset name cannot hold '/'");
    std::vector<std::string> dirs;
    if (fs::is_regular_file(path, ec)) {
      std::ifstream in(path);
      for (std::string line; std::getline(in, line);) {
        while (!line.empty() && (line.back() == '\r' || line.back() == ' ')) line.pop_back();
        if (line.empty() || line[0] == '#') continue;
        const fs::path p = fs::path(line).is_absolute() ? fs::path(line) : fs::path(path).parent_path() / line;
        dirs.push_back(p.string());
      }
      FLAT_CHECK(!dirs.empty(), path + ": the scene list is empty");
    } else {
      dirs = data::scene_dirs_under(path);
    }
    for (const auto& d : dirs) out.push_back({name, d});
  }
  return out;
}

std::string score_file(const std::string& out_dir, const SceneRef& s) {
  return out_dir + "/scores/" + s.dataset + "/" + fs::path(s.dir).filename().string() + ".json";
}

SceneScore score_from_file(const std::string& path) {
  std::ifstream in(path);
  try {
    return score_from_json(nlohmann::json::parse(in));
  } catch (const nlohmann::json::exception& e) {
    fail(path + ": malformed score file (" + e.what() + "); delete it to score the scene again");
  }
}

}  // namespace

EvalRunSummary run_evaluation(const EvalRunOptions& o) {
  EvalRunSummary summary;
  summary.out_dir = o.out_dir;
  FLAT_CHECK(!o.out_dir.empty(), "no output folder (--out)");
  const auto scenes = collect_scenes(o.datasets);  // bad dataset paths fail before anything is written

  auto trained = pipeline::load_trained_model(o.model, o.config, o.overrides);
  // The model by its canonical path: the same file spelled relative or absolute is the same model.
  const std::string spelled_id = trained.describe();
  std::string model_id = spelled_id;
  {
    std::error_code canon_ec;
    const auto canon = fs::weakly_canonical(trained.model_file, canon_ec);
    if (!canon_ec) model_id = canon.string() + spelled_id.substr(trained.model_file.size());
  }
  const std::string fingerprint = o.settings.fingerprint() + " config=" + pipeline::model_signature(trained.config).pipeline_config;
  std::error_code ec;
  fs::create_directories(o.out_dir + "/scores", ec);
  if (ec) fail(o.out_dir + ": cannot create the output folder (" + ec.message() + ")");
  setup_logging(o.log_level, o.out_dir + "/eval.log");

  // A folder holds the scores of one model and one set of settings.
  const std::string settings_file = o.out_dir + "/settings.json";
  nlohmann::json settings = {{"model", model_id}, {"settings", fingerprint}, {"name", o.name}};
  if (fs::exists(settings_file, ec)) {
    nlohmann::json old;
    try {
      std::ifstream in(settings_file);
      old = nlohmann::json::parse(in);
    } catch (const nlohmann::json::exception& e) {
      fail(settings_file + ": malformed (" + e.what() + ")");
    }
    const std::string old_model = old.value("model", ""), old_settings = old.value("settings", "");
    const bool same_model = old_model == model_id || old_model == spelled_id;  // (files of older versions)
    const bool same = same_model && old_settings == fingerprint;
    if (!same && !o.redo) {
      std::string what;
      if (!same_model) what += "\n  model: there " + old_model + ", now " + model_id;
      if (old_settings != fingerprint) what += "\n  settings: there " + old_settings + ", now " + fingerprint;
      fail(o.out_dir + ": holds scores of another model or other settings (" + settings_file +
           "); use a new --out folder, or --redo to score every scene again here:" + what);
    }
    if (o.redo || !same) {
      fs::remove_all(o.out_dir + "/scores", ec);
      fs::create_directories(o.out_dir + "/scores", ec);
    }
  }
  write_file_atomic(settings_file, settings.dump(2) + "\n");

  const at::Device device = [&] {
    FLAT_CHECK(o.device == "auto" || o.device == "cpu" || o.device == "cuda",
               "--device: expected auto, cpu or cuda, got '" + o.device + "'");
    if (o.device == "cuda") FLAT_CHECK(torch::cuda::is_available(), "--device cuda: no CUDA device is available");
    return (o.device == "cpu" || !torch::cuda::is_available()) ? at::Device(at::kCPU) : at::Device(at::kCUDA, 0);
  }();
  FLAT_CHECK(o.precision == "fp32" || o.precision == "bf16",
             "--precision: expected fp32 or bf16, got '" + o.precision + "'");
  auto settings_run = o.settings;
  settings_run.bf16 = device.is_cuda() && o.precision == "bf16";  // the CPU computes in fp32
  trained.decoder->to(device);
  pipeline::ScenePipeline pipe(trained.config, trained.decoder);
  loss::Lpips lpips{nullptr};
  if (!o.lpips_weights.empty()) {
    lpips = loss::Lpips();
    lpips->load(o.lpips_weights);
    lpips->to(device);
    lpips->eval();
  } else {
    spdlog::warn("no --lpips-weights: the LPIPS column stays empty");
  }
  spdlog::info("flat_eval: {} scenes, model {}, views '{}', SSIM {}", scenes.size(), model_id, o.settings.views,
               ssim_convention_name(o.settings.ssim));

  EvalResults results;
  results.name = o.name.empty() ? fs::path(trained.model_file).parent_path().filename().string() : o.name;
  results.model = model_id;
  results.settings = fingerprint;
  results.ssim = ssim_convention_name(o.settings.ssim);
  results.prune_opacity = trained.config.prune_opacity;
  spdlog::info("flat_eval: rendering the triangles of opacity >= {} (the model's pipeline.prune_opacity; flat_infer "
               "exports those >= its --prune-opacity, 0.05 by default: --set prune_opacity=0.05 scores the same)",
               trained.config.prune_opacity);
  // Baselines need the rest of each dataset: its scenes (swap partners) and
  // its frames by index (the leave-one-out mean). Scenes that cannot be read
  // fail below, with their error, and take no part in the baselines.
  std::vector<std::optional<data::Scene>> loaded(scenes.size());
  std::map<std::string, std::vector<size_t>> members;  // dataset -> readable scenes, in order
  std::map<std::string, FrameSums> frame_sums;
  {
    Progress reading("flat_eval baselines (reading the datasets' frames)", int64_t(scenes.size()));
    for (size_t i = 0; i < scenes.size(); ++i) {
      try {
        auto scene = data::read_scene(scenes[i].dir, /*check_files=*/true);
        data::choose_latent_set(scene, o.settings.latent_set);
        FrameSums sums_of_scene;
        add_frame_sums(sums_of_scene, scene, settings_run);  // whole or not at all
        frame_sums[scenes[i].dataset].add(sums_of_scene);
        loaded[i] = std::move(scene);
        members[scenes[i].dataset].push_back(i);
      } catch (const std::exception&) {
        // Reported when the scene is scored.
      }
      reading.step();
    }
    reading.finish();
  }
  auto partner_of = [&](size_t i) -> const data::Scene* {
    const auto& list = members[scenes[i].dataset];
    const auto at = std::find(list.begin(), list.end(), i);
    if (at == list.end()) return nullptr;
    const auto p = swap_partner(size_t(at - list.begin()), list.size());
    return p ? &*loaded[list[*p]] : nullptr;
  };

  Progress progress("flat_eval", int64_t(scenes.size()));
  double psnr_sum = 0, swap_sum = 0;
  int64_t psnr_count = 0, swap_count = 0;
  for (size_t index = 0; index < scenes.size(); ++index) {
    const auto& ref = scenes[index];
    const std::string file = score_file(o.out_dir, ref);
    SceneScore score;
    bool reused = false;
    if (fs::exists(file, ec)) {
      score = score_from_file(file);
      reused = score.ok;
    }
    if (!reused) {
      try {
        auto scene = loaded[index] ? *loaded[index] : data::read_scene(ref.dir, /*check_files=*/true);
        if (!loaded[index]) data::choose_latent_set(scene, o.settings.latent_set);
        BaselineInputs inputs;
        inputs.swap_with = partner_of(index);
        if (loaded[index]) inputs.frame_sums = &frame_sums[ref.dataset];
        score = evaluate_scene(pipe, scene, settings_run, lpips, inputs);
      } catch (const std::exception& e) {
        score = SceneScore{};
        score.scene = fs::path(ref.dir).filename().string();
        score.dir = ref.dir;
        score.error = exception_text(e);  // a libtorch error without its stack trace
        spdlog::warn("{}: failed: {}", ref.dir, score.error);
      }
      score.dataset = ref.dataset;
      write_file_atomic(file, score_to_json(score).dump(2) + "\n");
    }
    summary.reused += reused ? 1 : 0;
    summary.scored += (!reused && score.ok) ? 1 : 0;
    summary.failed += score.ok ? 0 : 1;
    results.scores.push_back(score);
    if (score.ok) psnr_sum += score.psnr, ++psnr_count;
    if (score.ok && std::isfinite(score.swap_psnr)) swap_sum += score.swap_psnr, ++swap_count;
    // Running means over the scenes scored so far (not the last scene's).
    progress.step(1, {{"mean psnr", psnr_count ? psnr_sum / double(psnr_count) : NAN},
                      {"mean swap", swap_count ? swap_sum / double(swap_count) : NAN}});
  }
  progress.finish();
  summary.scenes = int64_t(scenes.size());

  write_file_atomic(o.out_dir + "/scenes.csv", results_csv(results));
  write_file_atomic(o.out_dir + "/results.json", results_json(results).dump(2) + "\n");
  summary.table = table1_markdown({results});
  write_file_atomic(o.out_dir + "/table.md", summary.table);
  if (summary.failed > 0) {
    spdlog::warn("{} of {} scenes failed; the means cover the other {}:", summary.failed, summary.scenes,
                 summary.scenes - summary.failed);
    for (const auto& s : results.scores)
      if (!s.ok) spdlog::warn("  {}: {}", s.dir, s.error);
  }
  return summary;
}

std::string compare_runs(const std::vector<std::string>& out_dirs) {
  FLAT_CHECK(!out_dirs.empty(), "--compare: no result folders given");
  std::vector<EvalResults> runs;
  for (const auto& d : out_dirs) {
    const std::string file = fs::is_directory(d) ? d + "/results.json" : d;
    auto r = read_results_json(file);
    for (const auto& other : runs)
      if (other.name == r.name) r.name += " (" + fs::path(d).filename().string() + ")";
    runs.push_back(r);
  }
  const std::string seeds = seeds_markdown(runs);
  return table1_markdown(runs) + (seeds.empty() ? "" : "\n### Over seeds\n\n" + seeds);
}

}  // namespace flat::eval
