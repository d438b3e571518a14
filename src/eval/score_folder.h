// flat_eval's output folder as a store of scores that a rerun reuses:
// settings.json names the one model and settings whose scores it holds,
// scores/<dataset>/<scene>.json one scene's score each (evaluation_run.h).
#pragma once
#include <string>

#include "flat/eval/scene_evaluation.h"

namespace flat::eval {

// Whose scores a folder holds: the model by its canonical path (`spelled`
// as given, which older folders hold) and the evaluation settings.
struct ScoreOwner {
  std::string model, spelled_model, settings, name;
};

// Creates <out_dir>/scores; throws flat::Error naming the folder if it cannot.
void create_score_folder(const std::string& out_dir);

// Refuses a folder that holds another owner's scores unless `redo`; with
// `redo` or another owner the old scores go. Then writes settings.json.
void claim_score_folder(const std::string& out_dir, const ScoreOwner& owner, bool redo);

// <out_dir>/scores/<dataset>/<scene folder's name>.json
std::string score_file(const std::string& out_dir, const std::string& dataset, const std::string& scene_dir);

// A score file written earlier; throws flat::Error naming it when malformed.
SceneScore read_score_file(const std::string& path);

}  // namespace flat::eval
