// Logging: spdlog everywhere (spdlog::info(...)). setup_logging installs a
// console sink and, when given, a log file (e.g. <run>/logs/flat.log).
#pragma once
#include <string>

#include <spdlog/spdlog.h>

namespace flat {

// level: trace|debug|info|warn|error. Throws flat::Error on an unknown level.
void setup_logging(const std::string& level = "info", const std::string& log_file = "");

}  // namespace flat
