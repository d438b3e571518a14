#include "eval/score_folder.h"

#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "flat/eval/evaluation_report.h"

namespace flat::eval {
namespace fs = std::filesystem;

void create_score_folder(const std::string& out_dir) {
  std::error_code ec;
  fs::create_directories(out_dir + "/scores", ec);
  if (ec) fail(out_dir + ": cannot create the output folder (" + ec.message() + ")");
}

void claim_score_folder(const std::string& out_dir, const ScoreOwner& owner, bool redo) {
  const std::string settings_file = out_dir + "/settings.json";
  const nlohmann::json settings = {{"model", owner.model}, {"settings", owner.settings}, {"name", owner.name}};
  std::error_code ec;
  if (fs::exists(settings_file, ec)) {
    nlohmann::json old;
    try {
      std::ifstream in(settings_file);
      old = nlohmann::json::parse(in);
    } catch (const nlohmann::json::exception& e) {
      fail(settings_file + ": malformed (" + e.what() + ")");
    }
    const std::string old_model = old.value("model", ""), old_settings = old.value("settings", "");
    const bool same_model = old_model == owner.model || old_model == owner.spelled_model;  // (files of older versions)
    const bool same = same_model && old_settings == owner.settings;
    if (!same && !redo) {
      std::string what;
      if (!same_model) what += "\n  model: there " + old_model + ", now " + owner.model;
      if (old_settings != owner.settings) what += "\n  settings: there " + old_settings + ", now " + owner.settings;
      fail(out_dir + ": holds scores of another model or other settings (" + settings_file +
           "); use a new --out folder, or --redo to score every scene again here:" + what);
    }
    if (redo || !same) {
      fs::remove_all(out_dir + "/scores", ec);
      fs::create_directories(out_dir + "/scores", ec);
    }
  }
  write_file_atomic(settings_file, settings.dump(2) + "\n");
}

std::string score_file(const std::string& out_dir, const std::string& dataset, const std::string& scene_dir) {
  return out_dir + "/scores/" + dataset + "/" + fs::path(scene_dir).filename().string() + ".json";
}

SceneScore read_score_file(const std::string& path) {
  std::ifstream in(path);
  try {
    return score_from_json(nlohmann::json::parse(in));
  } catch (const nlohmann::json::exception& e) {
    fail(path + ": malformed score file (" + e.what() + "); delete it to score the scene again");
  }
}

}  // namespace flat::eval
