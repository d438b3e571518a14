// flat_eval's --scenes: the scene folders to score, each with its dataset's
// label (evaluation_run.h says what a spec may name).
#pragma once
#include <string>
#include <vector>

namespace flat::eval {

struct SceneRef {
  std::string dataset, dir;
};

// "NAME=PATH" | "PATH" -> the scene folders, labelled; NAME defaults to the
// folder's name. Throws flat::Error on an empty list or a bad name.
std::vector<SceneRef> collect_scenes(const std::vector<std::string>& specs);

}  // namespace flat::eval
