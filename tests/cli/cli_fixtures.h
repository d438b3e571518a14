// Fixtures of the tool tests: running a tool as a process, snapshots of
// folders (to show that earlier files are byte-identical after a failed or
// refused run), and small inputs written with the project's own writers.
#pragma once
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include "data/data_test_dirs.h"
#include "test_support.h"
#include "support/process.h"

namespace flat::test {

struct ToolResult {
  int rc = -1;
  std::string output;  // stdout and stderr together
};

// Runs build/<tool> with args; the output goes to <log_dir>/<tag>.txt.
inline ToolResult tool(const std::string& name, const std::vector<std::string>& args, const std::string& log_dir,
                       const std::string& tag) {
  std::vector<std::string> argv = {binary(name)};
  argv.insert(argv.end(), args.begin(), args.end());
  const std::string log = log_dir + "/" + tag + ".txt";
  ToolResult r;
  // One thread, and a wait policy chosen: the tools do not restart (see
  // cli::restart_with_sleeping_openmp_threads; tested on its own).
  r.rc = run(argv, log, {"OMP_NUM_THREADS=1", "OMP_WAIT_POLICY=PASSIVE"});
  r.output = read_file(log);
  return r;
}

// flat_latents over the scenes under `scenes` with a random-weight VAE of
// width 4 and 5-frame windows (the tool tests' latents), then `extra`.
inline ToolResult random_latents(const std::string& scenes, const std::string& log_dir, const std::string& tag,
                                 const std::vector<std::string>& extra = {}) {
  std::vector<std::string> args = {"--scenes", scenes, "--random-weights", "--dim", "4", "--window", "5"};
  args.insert(args.end(), extra.begin(), extra.end());
  return tool("flat_latents", args, log_dir, tag);
}

// Every regular file under `dir` (relative path -> bytes).
inline std::map<std::string, std::string> snapshot(const std::string& dir) {
  std::map<std::string, std::string> files;
  if (!std::filesystem::exists(dir)) return files;
  for (const auto& e : std::filesystem::recursive_directory_iterator(dir))
    if (e.is_regular_file()) files[std::filesystem::relative(e.path(), dir).string()] = read_file(e.path());
  return files;
}

inline void write_text(const std::string& path, const std::string& text) {
  std::filesystem::create_directories(std::filesystem::path(path).parent_path());
  std::ofstream(path, std::ios::binary) << text;
}

}  // namespace flat::test
