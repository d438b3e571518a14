// Tables of flat_eval's results: per-scene rows and per-dataset means as CSV,
// JSON and a Markdown table laid out like the paper's Table 1 (Method | per
// dataset PSNR, SSIM, LPIPS | geometry L1, cosine, depth SI-log, planar
// roughness over all datasets). Every
// table says how many scenes its means cover and how its metrics are defined.
#pragma once
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "flat/eval/scene_evaluation.h"

namespace flat::eval {

struct EvalResults {
  std::string name;      // the method's label in tables
  std::string model;     // model file and step
  std::string settings;  // EvalSettings::fingerprint()
  std::string ssim = "skimage";
  // Triangles below this opacity are dropped before rendering (the model's
  // pipeline.prune_opacity, or --set); NaN when the file does not say.
  double prune_opacity = NAN;
  std::vector<SceneScore> scores;  // in evaluation order, failures included
};

struct Means {
  std::string dataset;  // "" = all datasets
  int64_t scenes = 0, failed = 0, normal_scenes = 0, depth_scenes = 0;
  double psnr = NAN, ssim = NAN, lpips = NAN, normal_l1 = NAN, normal_cosine = NAN;
  // Depth (depth_metrics.h): means over the scored scenes that have each figure.
  double depth_si_log = NAN, planar_roughness = NAN;
  // Baselines (baselines.h), means over the scored scenes that have them.
  double mean_colour_psnr = NAN, dataset_mean_psnr = NAN, swap_psnr = NAN;
  int64_t random_latent_scenes = 0;  // scored scenes whose latents came from a random encoder
};

// Means over the scenes that were scored (failures counted, not averaged):
// one per dataset in order of first appearance, then the overall one.
std::vector<Means> dataset_means(const std::vector<SceneScore>& scores);

// One scene's row as JSON and back (null = NaN); throws nlohmann's exceptions.
nlohmann::json score_to_json(const SceneScore& score);
SceneScore score_from_json(const nlohmann::json& row);

std::string results_csv(const EvalResults& results);
nlohmann::json results_json(const EvalResults& results);
// Reads results.json back (for --compare); throws naming the file.
EvalResults read_results_json(const std::string& path);

// One row per run; datasets are the union over runs. Definitions follow the table.
std::string table1_markdown(const std::vector<EvalResults>& runs);

// Runs named "<row> seed <n>" grouped by row: per metric the mean over the
// seeds and the spread (max - min), and the baselines' means beside them, so
// that a gap between rows can be told from seed noise. "" when no row has two
// or more seeds.
std::string seeds_markdown(const std::vector<EvalResults>& runs);
// The row of a run name "<row> seed <n>" ("" when the name has no seed).
std::string seed_group(const std::string& name);

// The metric definitions printed under every table.
std::string metric_definitions(const std::string& ssim_convention);

}  // namespace flat::eval
