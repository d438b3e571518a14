#include "flat/eval/evaluation_run.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <optional>

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
#include "eval/scene_list.h"
#include "eval/score_folder.h"

namespace flat::eval {
namespace fs = std::filesystem;

namespace {

// ---- the run -------------------------------------------------------------------
// One call of run_evaluation, section by section: run_evaluation calls these
// in the order they are declared. What one section leaves for the next is a
// member.
class Evaluation {
 public:
  explicit Evaluation(const EvalRunOptions& o) : o_(o) {}

  // The scenes (bad dataset paths fail before anything is written) and the
  // trained model, with whose scores the output folder will hold.
  void load_scenes_and_model();
  // scores/, eval.log and settings.json (another model's folder is refused).
  void open_output_folder();
  // The device, the pipeline, LPIPS and the results' header.
  void prepare_scoring();
  // What the baselines need of each dataset: its scenes and their frames.
  void read_datasets();
  // Every scene: its score file reused, or scored and written.
  void score_scenes();
  // scenes.csv, results.json, table.md; the failed scenes named.
  EvalRunSummary write_results();

 private:
  SceneScore score_scene(size_t index);
  const data::Scene* swap_partner_of(size_t index) const;

  const EvalRunOptions& o_;
  EvalRunSummary summary_;
  std::vector<SceneRef> scenes_;
  pipeline::TrainedModel trained_;
  ScoreOwner owner_;  // the model's id and the settings' fingerprint
  at::Device device_{at::kCPU};
  EvalSettings settings_;  // o.settings, with bf16 as the device allows
  std::optional<pipeline::ScenePipeline> pipe_;
  loss::Lpips lpips_{nullptr};
  EvalResults results_;
  // The baselines' inputs. Scenes that cannot be read fail when scored, with
  // their error, and take no part in the baselines.
  std::vector<std::optional<data::Scene>> loaded_;
  std::map<std::string, std::vector<size_t>> members_;  // dataset -> readable scenes, in order
  std::map<std::string, FrameSums> frame_sums_;
};

void Evaluation::load_scenes_and_model() {
  summary_.out_dir = o_.out_dir;
  FLAT_CHECK(!o_.out_dir.empty(), "no output folder (--out)");
  scenes_ = collect_scenes(o_.datasets);
  trained_ = pipeline::load_trained_model(o_.model, o_.config, o_.overrides);
  // The model by its canonical path: the same file spelled relative or absolute is the same model.
  owner_.spelled_model = trained_.describe();
  owner_.model = owner_.spelled_model;
  std::error_code canon_ec;
  const auto canon = fs::weakly_canonical(trained_.model_file, canon_ec);
  if (!canon_ec) owner_.model = canon.string() + owner_.spelled_model.substr(trained_.model_file.size());
  owner_.settings =
      o_.settings.fingerprint() + " config=" + pipeline::model_signature(trained_.config).pipeline_config;
  owner_.name = o_.name;
}

void Evaluation::open_output_folder() {
  create_score_folder(o_.out_dir);
  setup_logging(o_.log_level, o_.out_dir + "/eval.log");
  claim_score_folder(o_.out_dir, owner_, o_.redo);
}

void Evaluation::prepare_scoring() {
  FLAT_CHECK(o_.device == "auto" || o_.device == "cpu" || o_.device == "cuda",
             "--device: expected auto, cpu or cuda, got '" + o_.device + "'");
  if (o_.device == "cuda") FLAT_CHECK(torch::cuda::is_available(), "--device cuda: no CUDA device is available");
  device_ = (o_.device == "cpu" || !torch::cuda::is_available()) ? at::Device(at::kCPU) : at::Device(at::kCUDA, 0);
  FLAT_CHECK(o_.precision == "fp32" || o_.precision == "bf16",
             "--precision: expected fp32 or bf16, got '" + o_.precision + "'");
  settings_ = o_.settings;
  settings_.bf16 = device_.is_cuda() && o_.precision == "bf16";  // the CPU computes in fp32
  trained_.decoder->to(device_);
  pipe_.emplace(trained_.config, trained_.decoder);
  if (!o_.lpips_weights.empty()) {
    lpips_ = loss::Lpips();
    lpips_->load(o_.lpips_weights);
    lpips_->to(device_);
    lpips_->eval();
  } else {
    spdlog::warn("no --lpips-weights: the LPIPS column stays empty");
  }
  spdlog::info("flat_eval: {} scenes, model {}, views '{}', SSIM {}", scenes_.size(), owner_.model, o_.settings.views,
               ssim_convention_name(o_.settings.ssim));

  results_.name = o_.name.empty() ? fs::path(trained_.model_file).parent_path().filename().string() : o_.name;
  results_.model = owner_.model;
  results_.settings = owner_.settings;
  results_.ssim = ssim_convention_name(o_.settings.ssim);
  results_.prune_opacity = trained_.config.prune_opacity;
  spdlog::info("flat_eval: rendering the triangles of opacity >= {} (the model's pipeline.prune_opacity, what "
               "flat_infer exports by default; --set pipeline.prune_opacity=X scores its --prune-opacity X)",
               trained_.config.prune_opacity);
}

// Baselines need the rest of each dataset: its scenes (swap partners) and
// its frames by index (the leave-one-out mean).
void Evaluation::read_datasets() {
  loaded_.resize(scenes_.size());
  Progress reading("flat_eval baselines (reading the datasets' frames)", int64_t(scenes_.size()));
  for (size_t i = 0; i < scenes_.size(); ++i) {
    try {
      auto scene = data::read_scene(scenes_[i].dir, /*check_files=*/true);
      data::choose_latent_set(scene, o_.settings.latent_set);
      FrameSums sums_of_scene;
      add_frame_sums(sums_of_scene, scene, settings_);  // whole or not at all
      frame_sums_[scenes_[i].dataset].add(sums_of_scene);
      loaded_[i] = std::move(scene);
      members_[scenes_[i].dataset].push_back(i);
    } catch (const std::exception&) {
      // Reported when the scene is scored.
    }
    reading.step();
  }
  reading.finish();
}

const data::Scene* Evaluation::swap_partner_of(size_t index) const {
  const auto found = members_.find(scenes_[index].dataset);
  if (found == members_.end()) return nullptr;
  const auto& list = found->second;
  const auto at = std::find(list.begin(), list.end(), index);
  if (at == list.end()) return nullptr;
  const auto p = swap_partner(size_t(at - list.begin()), list.size());
  return p ? &*loaded_[list[*p]] : nullptr;
}

void Evaluation::score_scenes() {
  Progress progress("flat_eval", int64_t(scenes_.size()));
  double psnr_sum = 0, swap_sum = 0;
  int64_t psnr_count = 0, swap_count = 0;
  for (size_t index = 0; index < scenes_.size(); ++index) {
    const std::string file = score_file(o_.out_dir, scenes_[index].dataset, scenes_[index].dir);
    SceneScore score;
    bool reused = false;
    std::error_code ec;
    if (fs::exists(file, ec)) {
      score = read_score_file(file);
      reused = score.ok;
    }
    if (!reused) {
      score = score_scene(index);
      write_file_atomic(file, score_to_json(score).dump(2) + "\n");
    }
    summary_.reused += reused ? 1 : 0;
    summary_.scored += (!reused && score.ok) ? 1 : 0;
    summary_.failed += score.ok ? 0 : 1;
    results_.scores.push_back(score);
    if (score.ok) psnr_sum += score.psnr, ++psnr_count;
    if (score.ok && std::isfinite(score.swap_psnr)) swap_sum += score.swap_psnr, ++swap_count;
    // Running means over the scenes scored so far (not the last scene's).
    progress.step(1, {{"mean psnr", psnr_count ? psnr_sum / double(psnr_count) : NAN},
                      {"mean swap", swap_count ? swap_sum / double(swap_count) : NAN}});
  }
  progress.finish();
  summary_.scenes = int64_t(scenes_.size());
}

// A scene that fails is a score with its error, not the end of the run.
SceneScore Evaluation::score_scene(size_t index) {
  const auto& ref = scenes_[index];
  SceneScore score;
  try {
    auto scene = loaded_[index] ? *loaded_[index] : data::read_scene(ref.dir, /*check_files=*/true);
    if (!loaded_[index]) data::choose_latent_set(scene, o_.settings.latent_set);
    BaselineInputs inputs;
    inputs.swap_with = swap_partner_of(index);
    if (loaded_[index]) inputs.frame_sums = &frame_sums_[ref.dataset];
    score = evaluate_scene(*pipe_, scene, settings_, lpips_, inputs);
  } catch (const std::exception& e) {
    score = SceneScore{};
    score.scene = fs::path(ref.dir).filename().string();
    score.dir = ref.dir;
    score.error = exception_text(e);  // a libtorch error without its stack trace
    spdlog::warn("{}: failed: {}", ref.dir, score.error);
  }
  score.dataset = ref.dataset;
  return score;
}

EvalRunSummary Evaluation::write_results() {
  write_file_atomic(o_.out_dir + "/scenes.csv", results_csv(results_));
  write_file_atomic(o_.out_dir + "/results.json", results_json(results_).dump(2) + "\n");
  summary_.table = table1_markdown({results_});
  write_file_atomic(o_.out_dir + "/table.md", summary_.table);
  if (summary_.failed > 0) {
    spdlog::warn("{} of {} scenes failed; the means cover the other {}:", summary_.failed, summary_.scenes,
                 summary_.scenes - summary_.failed);
    for (const auto& s : results_.scores)
      if (!s.ok) spdlog::warn("  {}: {}", s.dir, s.error);
  }
  return summary_;
}

}  // namespace

EvalRunSummary run_evaluation(const EvalRunOptions& o) {
  Evaluation run(o);
  run.load_scenes_and_model();
  run.open_output_folder();
  run.prepare_scoring();
  run.read_datasets();
  run.score_scenes();
  return run.write_results();
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
