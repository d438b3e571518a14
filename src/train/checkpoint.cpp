#include "flat/train/checkpoint.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <sstream>

#include <ATen/Context.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "flat/model/weights.h"

namespace flat::train {
namespace fs = std::filesystem;

namespace {

constexpr const char* kPrefix = "step_";
constexpr const char* kIncomplete = ".incomplete-";

std::string step_name(int64_t step) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%s%08lld", kPrefix, static_cast<long long>(step));
  return buf;
}

// step_00001000 -> 1000; -1 for anything else.
int64_t step_of(const std::string& name) {
  if (name.rfind(kPrefix, 0) != 0 || name.size() <= std::string(kPrefix).size()) return -1;
  int64_t v = 0;
  for (char c : name.substr(std::string(kPrefix).size())) {
    if (c < '0' || c > '9') return -1;
    v = v * 10 + (c - '0');
  }
  return v;
}

// Makes the folder's entries (the files in it, a rename into it) durable;
// best effort: a filesystem that cannot sync a folder is not an error.
void fsync_dir(const std::string& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

void maybe_kill_for_test(int64_t step) {
  const char* v = std::getenv(kKillInCheckpointEnv);
  if (v && std::to_string(step) == v) std::raise(SIGKILL);
}

// "'<key>': N non-finite value(s)" for the first floating tensor of `m` that
// holds NaN or Inf; "" when all are finite.
std::string first_nonfinite(const TensorMap& m) {
  for (const auto& [name, t] : m) {
    if (!t.defined() || !t.is_floating_point() || t.numel() == 0) continue;
    const int64_t bad = (~at::isfinite(t)).sum().item<int64_t>();
    if (bad > 0) return "'" + name + "': " + std::to_string(bad) + " non-finite value(s) (NaN or Inf)";
  }
  return "";
}

// The consecutive_skips a checkpoint was written with; -1 when unreadable.
int64_t consecutive_skips_of(const std::string& dir) {
  try {
    std::ifstream in(dir + "/trainer.json");
    return nlohmann::json::parse(in).at("consecutive_skips").get<int64_t>();
  } catch (const std::exception&) {
    return -1;
  }
}

void remove_incomplete(const std::string& checkpoints_dir) {
  std::error_code ec;
  if (!fs::is_directory(checkpoints_dir, ec)) return;
  for (const auto& e : fs::directory_iterator(checkpoints_dir, ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind(kIncomplete, 0) == 0) {
      spdlog::warn("checkpoints: removing '{}', left by a write that did not finish", e.path().string());
      fs::remove_all(e.path(), ec);
    }
  }
}

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path + ": cannot open for reading");
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

}  // namespace

std::string checkpoint_folder(const std::string& checkpoints_dir, int64_t step) {
  return (fs::path(checkpoints_dir) / step_name(step)).string();
}

std::vector<std::string> list_checkpoints(const std::string& checkpoints_dir) {
  std::vector<std::pair<int64_t, std::string>> found;
  std::error_code ec;
  if (!fs::is_directory(checkpoints_dir, ec)) return {};
  for (const auto& e : fs::directory_iterator(checkpoints_dir, ec)) {
    const int64_t step = step_of(e.path().filename().string());
    if (step >= 0 && e.is_directory() && fs::exists(e.path() / "trainer.json")) found.push_back({step, e.path().string()});
  }
  std::sort(found.begin(), found.end());
  std::vector<std::string> dirs;
  for (auto& f : found) dirs.push_back(f.second);
  return dirs;
}

std::string latest_checkpoint(const std::string& checkpoints_dir) {
  remove_incomplete(checkpoints_dir);
  auto all = list_checkpoints(checkpoints_dir);
  return all.empty() ? std::string() : all.back();
}

std::string save_checkpoint(const std::string& checkpoints_dir, const TrainerState& state,
                            const torch::nn::Module& model, const ModelSignature& signature, const optim::AdamW& optimiser,
                            int64_t keep) {
  const std::string name = step_name(state.step);
  const std::string final_dir = checkpoints_dir + "/" + name;
  // A checkpoint of NaN weights would only ever be resumed into NaN steps.
  TensorMap weights;
  for (const auto& p : model.named_parameters()) weights[p.key()] = p.value();
  for (const auto& b : model.named_buffers()) weights[b.key()] = b.value();
  const std::string bad = first_nonfinite(weights);
  if (!bad.empty())
    fail(final_dir + ": not written: the model's weights hold NaN or Inf (" + bad +
         "); the checkpoints already there are left as they were");
  std::error_code ec;
  fs::create_directories(checkpoints_dir, ec);
  if (ec) fail(checkpoints_dir + ": cannot create the checkpoint folder (" + ec.message() + ")");
  const std::string tmp = checkpoints_dir + "/" + kIncomplete + name + "." + std::to_string(::getpid());
  fs::remove_all(tmp, ec);
  fs::create_directories(tmp, ec);
  if (ec) fail(tmp + ": cannot create (" + ec.message() + ")");

  auto meta = pipeline::signature_metadata(signature);
  meta.insert({{"producer", "flat_train"}, {"stage", state.stage}, {"step", std::to_string(state.step)}});
  model::save_weights(model, tmp + "/model.safetensors", model::WeightNaming::wan, meta);
  maybe_kill_for_test(state.step);
  save_safetensors(tmp + "/optimizer.safetensors", optimiser.state(), {{"optimiser", "adamw"}});
  save_safetensors(tmp + "/rng.safetensors", capture_rng());
  nlohmann::json j = {{"format", "flat-checkpoint-1"},
                      {"step", state.step},
                      {"stage", state.stage},
                      {"skipped_steps", state.skipped_steps},
                      {"consecutive_skips", state.consecutive_skips},
                      {"model_signature", signature.yaml},
                      {"config", state.config_yaml}};
  write_file_atomic(tmp + "/trainer.json", j.dump(2) + "\n");  // written last: marks the folder complete
  fsync_dir(tmp);

  if (fs::exists(final_dir, ec)) fs::remove_all(final_dir, ec);  // same step written again (a resumed run)
  fs::rename(tmp, final_dir, ec);
  if (ec) fail(final_dir + ": cannot move the finished checkpoint into place (" + ec.message() + ")");
  fsync_dir(checkpoints_dir);

  // The newest `keep`, and the newest good one (written while no step was
  // being skipped) whatever its age: never pruned to make room for a worse one.
  auto all = list_checkpoints(checkpoints_dir);
  std::string last_good;
  for (auto it = all.rbegin(); it != all.rend() && last_good.empty(); ++it)
    if (consecutive_skips_of(*it) == 0) last_good = *it;
  for (size_t i = 0; i + size_t(keep) < all.size(); ++i)
    if (all[i] != last_good) fs::remove_all(all[i], ec);
  return final_dir;
}

LoadedCheckpoint read_checkpoint(const std::string& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) fail(dir + ": checkpoint folder not found");
  LoadedCheckpoint c;
  c.dir = dir;
  const std::string meta = dir + "/trainer.json";
  if (!fs::exists(meta, ec)) fail(meta + ": missing; '" + dir + "' is not a complete checkpoint");
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(read_text(meta));
    c.state.step = j.at("step").get<int64_t>();
    c.state.stage = j.at("stage").get<std::string>();
    c.state.skipped_steps = j.at("skipped_steps").get<int64_t>();
    c.state.consecutive_skips = j.at("consecutive_skips").get<int64_t>();
    c.state.config_yaml = j.at("config").get<std::string>();
    c.signature.yaml = j.at("model_signature").get<std::string>();
  } catch (const nlohmann::json::exception& e) {
    fail(meta + ": not a valid checkpoint record (" + e.what() + ")");
  }
  FLAT_CHECK(c.state.step >= 0, meta + ": negative step");
  c.model = load_safetensors(dir + "/model.safetensors");
  c.optimiser = load_safetensors(dir + "/optimizer.safetensors");
  c.rng = load_safetensors(dir + "/rng.safetensors");
  return c;
}

std::optional<LoadedCheckpoint> load_newest_intact_checkpoint(const std::string& checkpoints_dir,
                                                               std::vector<std::string>* skipped) {
  remove_incomplete(checkpoints_dir);
  // Every step_N folder, trainer.json or not (one without it is named, not passed over in silence).
  std::vector<std::pair<int64_t, std::string>> found;
  std::error_code ec;
  if (fs::is_directory(checkpoints_dir, ec))
    for (const auto& e : fs::directory_iterator(checkpoints_dir, ec)) {
      const int64_t step = step_of(e.path().filename().string());
      if (step >= 0 && e.is_directory()) found.push_back({step, e.path().string()});
    }
  std::sort(found.rbegin(), found.rend());
  std::vector<std::pair<std::string, std::string>> broken;  // folder, why
  for (const auto& [step, dir] : found) {
    std::string why;
    try {
      LoadedCheckpoint c = read_checkpoint(dir);
      why = first_nonfinite(c.model);
      if (!why.empty()) why = dir + "/model.safetensors: " + why;
      else if (!(why = first_nonfinite(c.optimiser)).empty()) why = dir + "/optimizer.safetensors: " + why;
      if (why.empty()) {
        for (const auto& [bad_dir, reason] : broken) {
          const std::string aside = bad_dir + ".broken-" + std::to_string(::getpid());
          fs::rename(bad_dir, aside, ec);
          spdlog::warn("resume: skipped checkpoint {}: {}; {}", bad_dir, reason,
                       ec ? "left in place (cannot move it aside: " + ec.message() + ")"
                          : "moved to " + aside + " for inspection");
          if (skipped) skipped->push_back(bad_dir + ": " + reason);
        }
        if (!broken.empty()) spdlog::warn("resume: falling back to {}, the newest intact checkpoint", dir);
        return c;
      }
    } catch (const std::exception& e) {
      why = e.what();
    }
    broken.push_back({dir, why});
  }
  if (broken.empty()) return std::nullopt;
  std::string list;
  for (const auto& [dir, why] : broken) list += "\n  " + dir + ": " + why;
  fail(checkpoints_dir + ": no intact checkpoint to resume from; every one fails:" + list);
}

TensorMap capture_rng() {
  TensorMap m;
  {
    at::Generator cpu_gen = at::detail::getDefaultCPUGenerator();
    std::lock_guard<std::mutex> lock(cpu_gen.mutex());
    m["cpu"] = cpu_gen.get_state();
  }
  if (at::hasCUDA()) {
    for (int i = 0; i < int(at::getNumGPUs()); ++i) {
      at::Generator gen = at::globalContext().defaultGenerator(at::Device(at::kCUDA, c10::DeviceIndex(i)));
      std::lock_guard<std::mutex> lock(gen.mutex());
      m["cuda." + std::to_string(i)] = gen.get_state();
    }
  }
  return m;
}

void restore_rng(const TensorMap& rng, const std::string& label) {
  auto cpu = rng.find("cpu");
  FLAT_CHECK(cpu != rng.end(), label + ": no 'cpu' generator state");
  at::Generator cpu_gen = at::detail::getDefaultCPUGenerator();  // a handle: shares the global state
  {
    std::lock_guard<std::mutex> lock(cpu_gen.mutex());
    cpu_gen.set_state(cpu->second);
  }
  for (const auto& [name, state] : rng) {
    if (name.rfind("cuda.", 0) != 0 || !at::hasCUDA()) continue;
    const int i = std::stoi(name.substr(5));
    if (i < int(at::getNumGPUs())) {
      at::Generator gen = at::globalContext().defaultGenerator(at::Device(at::kCUDA, c10::DeviceIndex(i)));
      std::lock_guard<std::mutex> lock(gen.mutex());
      gen.set_state(state);
    }
  }
}

}  // namespace flat::train
