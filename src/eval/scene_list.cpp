#include "eval/scene_list.h"

#include <filesystem>
#include <fstream>

#include "flat/core/error.h"
#include "flat/data/scene.h"

namespace flat::eval {
namespace fs = std::filesystem;

namespace {

// A text file of scene folders, one a line (# comments); relative to the file.
std::vector<std::string> read_scene_list(const std::string& path) {
  std::vector<std::string> dirs;
  std::ifstream in(path);
  for (std::string line; std::getline(in, line);) {
    while (!line.empty() && (line.back() == '\r' || line.back() == ' ')) line.pop_back();
    if (line.empty() || line[0] == '#') continue;
    const fs::path p = fs::path(line).is_absolute() ? fs::path(line) : fs::path(path).parent_path() / line;
    dirs.push_back(p.string());
  }
  FLAT_CHECK(!dirs.empty(), path + ": the scene list is empty");
  return dirs;
}

}  // namespace

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
    const std::vector<std::string> dirs =
        fs::is_regular_file(path, ec) ? read_scene_list(path) : data::scene_dirs_under(path);
    for (const auto& d : dirs) out.push_back({name, d});
  }
  return out;
}

}  // namespace flat::eval
