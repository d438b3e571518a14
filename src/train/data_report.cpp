#include "flat/train/data_report.h"

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "flat/core/error.h"

namespace flat::train {

namespace {

// One geometry term against the scenes that carry its targets.
void check_term(const char* term, const char* key, double lambda, int64_t with, int64_t scenes,
                const std::string& policy) {
  if (lambda <= 0) return;
  if (with == 0) {
    const std::string what = std::string("loss.") + key + " is " + std::to_string(lambda) + " but none of the " +
                             std::to_string(scenes) + " training scenes has " + term +
                             " maps: that term would train nothing (flat_import --" + term +
                             " DIR attaches a predictor's maps; docs/data_tools.md)";
    if (policy == "fail")
      fail(what + ". Set loss." + key + ": 0 to train without it, or loss.missing_geometry: warn");
    spdlog::warn("{} (loss.missing_geometry: warn)", what);
  } else if (with < scenes) {
    spdlog::warn("the {} term trains on the {} of {} training scenes that have {} maps", term, with, scenes, term);
  }
}

nlohmann::json loader_json(const data::Loader& l) {
  nlohmann::json datasets = nlohmann::json::array();
  for (const auto& r : l.reports()) {
    nlohmann::json other = nlohmann::json::object();
    for (const auto& [sets, n] : r.other_sets) other[sets] = n;
    datasets.push_back({{"root", r.root},
                        {"weight", r.weight},
                        {"scenes_found", r.found},
                        {"scenes_used", r.used},
                        {"left_out_too_short", r.short_scenes},
                        {"left_out_without_latent_set", r.missing_set},
                        {"left_out_unreadable", r.bad},
                        {"latent_sets_held_instead", other},
                        {"with_depth", r.with_depth},
                        {"with_normals", r.with_normals}});
  }
  const auto& c = l.config();
  return {{"scenes", l.scene_count()},
          {"with_depth", l.scenes_with_depth()},
          {"with_normals", l.scenes_with_normals()},
          {"latent_set", c.latents ? data::latent_set_key(c.height, c.width, c.input_frames) : ""},
          {"datasets", datasets}};
}

}  // namespace

void check_geometry_targets(const loss::LossConfig& loss, const data::Loader& train) {
  const int64_t n = train.scene_count();
  check_term("depth", "lambda_depth", loss.lambda_depth, train.scenes_with_depth(), n, loss.missing_geometry);
  check_term("normals", "lambda_normal", loss.lambda_normal, train.scenes_with_normals(), n, loss.missing_geometry);
}

std::vector<std::string> data_summary(const data::Loader& train, const data::Loader* val, int64_t world_size,
                                      int64_t batch_per_rank) {
  std::vector<std::string> lines;
  lines.push_back(fmt::format(
      "data: {} training scenes ({} with depth, {} with normals){}; batch {} per rank x {} rank(s) = {}",
      train.scene_count(), train.scenes_with_depth(), train.scenes_with_normals(),
      val ? ", " + std::to_string(val->scene_count()) + " validation scenes (" +
                std::to_string(val->scenes_with_depth()) + " with depth, " +
                std::to_string(val->scenes_with_normals()) + " with normals)"
          : "",
      batch_per_rank, world_size, batch_per_rank * world_size));
  for (const auto* l : {&train, val}) {
    if (!l) continue;
    const auto& c = l->config();
    for (const auto& r : l->reports())
      lines.push_back(fmt::format(
          "data: {} dataset '{}' (weight {}): {} of {} scenes used ({} too short{}, {} unreadable)",
          l == &train ? "training" : "validation", r.root, r.weight, r.used, r.found, r.short_scenes,
          c.latents ? fmt::format(", {} without latent set {}", r.missing_set,
                                  data::latent_set_key(c.height, c.width, c.input_frames))
                    : "",
          r.bad));
  }
  return lines;
}

std::string data_report_json(const data::Loader& train, const data::Loader* val, int64_t world_size,
                             int64_t batch_per_rank) {
  nlohmann::json j;
  j["train"] = loader_json(train);
  if (val) j["validation"] = loader_json(*val);
  j["batch_per_rank"] = batch_per_rank;
  j["ranks"] = world_size;
  j["effective_batch"] = batch_per_rank * world_size;
  return j.dump(2) + "\n";
}

}  // namespace flat::train
