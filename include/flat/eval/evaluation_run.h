// flat_eval's batch evaluation: a trained model over one or more datasets of
// scenes, scored as Table 1 (scene_evaluation.h), with a progress line and
// ETA over scenes. Resumable: each scene's score is its own file, written when
// the scene is done, and a rerun into the same folder scores only the scenes
// that have none (a failed scene is tried again). A rerun with another model
// or other settings is refused (--redo starts the folder's scores afresh).
//
//   <out>/settings.json        model and evaluation settings
//   <out>/scores/<dataset>/<scene>.json
//   <out>/scenes.csv, <out>/results.json, <out>/table.md   (rewritten at the end)
//   <out>/eval.log
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "flat/eval/evaluation_report.h"
#include "flat/eval/scene_evaluation.h"

namespace flat::eval {

struct EvalRunOptions {
  std::string model;                   // run folder | checkpoint folder | model file
  std::string config;                  // pipeline keys (YAML) layered over the model's own config
  std::vector<std::string> overrides;  // pipeline keys
  // Each: "NAME=PATH" or "PATH"; PATH is a folder of scene folders, one scene
  // folder, or a text file listing scene folders (one per line, # comments).
  // NAME labels the dataset in tables (default: the folder's name).
  std::vector<std::string> datasets;
  std::string out_dir;
  std::string name;  // the method's label (default: the model's run folder name)
  EvalSettings settings;
  std::string device = "auto", precision = "bf16";  // precision: bf16 applies on CUDA only
  std::string lpips_weights;  // "" = no LPIPS column
  bool redo = false;
  std::string log_level = "info";
};

struct EvalRunSummary {
  int64_t scenes = 0, scored = 0, reused = 0, failed = 0;
  std::string table;  // table.md's text
  std::string out_dir;
};

EvalRunSummary run_evaluation(const EvalRunOptions& options);

// --compare: the runs' results.json side by side (one row per run).
std::string compare_runs(const std::vector<std::string>& out_dirs);

}  // namespace flat::eval
