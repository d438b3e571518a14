// A run folder: <root>/config.yaml (the effective config), logs/, checkpoints/,
// renders/, metrics/. Created on demand; an existing run is resumed, never wiped.
#pragma once
#include <string>

namespace flat {

struct RunDir {
  std::string root;
  std::string config_file() const { return root + "/config.yaml"; }
  std::string logs() const { return root + "/logs"; }
  std::string checkpoints() const { return root + "/checkpoints"; }
  std::string renders() const { return root + "/renders"; }
  std::string metrics() const { return root + "/metrics"; }
  std::string log_file() const { return logs() + "/flat.log"; }

  // Creates root and every sub-folder; throws flat::Error naming the path.
  static RunDir create(const std::string& root);
};

}  // namespace flat
