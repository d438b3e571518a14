// The shared command-line vocabulary (include/flat/core/cli.h, docs/cli.md).
#include "flat/core/cli.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <unistd.h>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <map>
#include <sstream>
#include <utility>

#include <ATen/Parallel.h>
#include <spdlog/spdlog.h>
#include <yaml-cpp/yaml.h>

#if FLAT_WITH_CUDA
#include <cuda_runtime_api.h>
#endif

#include <torch/cuda.h>

#include "flat/core/error.h"
#include "flat/core/log.h"
#include "flat/core/shape.h"

namespace flat::cli {

void add_common(CLI::App& app, const std::string& tool, std::string& log_level) {
  // Every default in --help, also for options added after this call.
  app.option_defaults()->always_capture_default();
  app.set_version_flag("--version", tool + " " + kVersion);
  app.add_option("--log-level", log_level, "trace | debug | info | warn | error")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error"}))
      ->capture_default_str();
}

CLI::Option* add_device(CLI::App& app, std::string& device) {
  return app.add_option("--device", device, "auto (cuda when present) | cpu | cuda")
      ->check(CLI::IsMember({"auto", "cpu", "cuda"}))
      ->capture_default_str();
}

CLI::Option* add_precision(CLI::App& app, std::string& precision) {
  return app.add_option("--precision", precision, "compute dtype: fp32 | bf16")
      ->check(CLI::IsMember({"fp32", "bf16"}))
      ->capture_default_str();
}

CLI::Option* add_store(CLI::App& app, std::string& store) {
  return app.add_option("--store", store, "stored dtype: fp32 | bf16 | fp16")
      ->check(CLI::IsMember({"fp32", "bf16", "fp16"}))
      ->capture_default_str();
}

CLI::Option* add_threads(CLI::App& app, int& threads) {
  return app.add_option("--threads", threads,
                        "CPU threads (0: every core; give each of several tools run side by side its share)")
      ->check(CLI::Range(0, 4096))
      ->capture_default_str();
}

CLI::Option* add_window_fn(CLI::App& app, std::string& window_fn) {
  return app.add_option("--window-fn", window_fn, "window function: flat (paper) | ts (Triangle Splatting)")
      ->check(CLI::IsMember({"flat", "ts"}))
      ->capture_default_str();
}

namespace {

// Old flag names per app or subcommand: old -> new. Tools register them once, before parsing.
std::map<const CLI::App*, std::vector<std::pair<std::string, std::string>>>& old_names() {
  static std::map<const CLI::App*, std::vector<std::pair<std::string, std::string>>> names;
  return names;
}

const std::string* new_name_of(const CLI::App* app, const std::string& name) {
  auto it = old_names().find(app);
  if (it == old_names().end()) return nullptr;
  for (const auto& [old_name, new_name] : it->second)
    if (old_name == name) return &new_name;
  return nullptr;
}

}  // namespace

void add_old_name(CLI::App& app, const std::string& old_name, const std::string& new_name) {
  old_names()[&app].emplace_back(old_name, new_name);
}

void rename_old_names(const CLI::App& app, int argc, char** argv) {
  if (old_names().empty() || argc < 1) return;
  const CLI::App* current = &app;
  std::string where = argv[0];
  where = where.substr(where.find_last_of('/') + 1);
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--") break;
    if (arg.rfind("--", 0) == 0) {
      const size_t eq = arg.find('=');
      const std::string name = arg.substr(0, eq);
      // Options of an enclosing app stay valid after a subcommand's name.
      for (const CLI::App* a = current; a != nullptr; a = a->get_parent()) {
        const std::string* new_name = new_name_of(a, name);
        if (new_name == nullptr) continue;
        std::cerr << where << ": warning: " << name << " is an old name; use " << *new_name
                  << " (the old name still works, hidden from --help)\n";
        const std::string renamed = *new_name + (eq == std::string::npos ? "" : arg.substr(eq));
        argv[i] = strdup(renamed.c_str());  // lives to the end: the restart and --nproc read argv later
        break;
      }
      continue;
    }
    if (arg.empty() || arg[0] == '-') continue;
    for (const CLI::App* sub : current->get_subcommands([](const CLI::App*) { return true; }))
      if (sub->get_name() == arg) {
        current = sub;
        where += " " + arg;
        break;
      }
  }
}

CLI::Option* add_set(CLI::App& app, std::vector<std::string>& overrides, const std::string& example) {
  return app
      .add_option("--set", overrides,
                  "override a config key by its full key path, as flat_train's --set (repeat it): --set " + example)
      ->take_all();
}

void parse_size_option(const std::string& text, int64_t& height, int64_t& width, const std::string& tool) {
  if (!text.empty() && !parse_size(text, height, width))
    throw UsageError(tool + ": --size must be HxW (e.g. 176x320), got '" + text + "'");
}

std::vector<std::string> section_overrides(const std::vector<std::string>& overrides, const std::string& section,
                                           const std::string& section_yaml, const std::string& tool) {
  const YAML::Node keys = YAML::Load(section_yaml);
  const std::string prefix = section + ".";
  std::vector<std::string> relative;
  for (const auto& ov : overrides) {
    if (ov.rfind(prefix, 0) == 0) {
      relative.push_back(ov.substr(prefix.size()));
      continue;
    }
    const std::string first = ov.substr(0, std::min(ov.find('.'), ov.find('=')));
    if (keys.IsMap() && keys[first]) {
      std::cerr << tool << ": warning: --set " << ov << " is the old " << section
                << "-relative spelling; use --set " << prefix << ov << " (full key paths, as flat_train's)\n";
      relative.push_back(ov);
      continue;
    }
    throw UsageError(tool + ": --set " + ov + ": " + tool + " reads only the model's " + section +
                     " config; give its keys by their full path, " + prefix + "<key> (e.g. --set " + prefix +
                     "prune_opacity=0.4); '" + first + "' is not a key of " + section);
  }
  return relative;
}

void apply_threads(int threads) {
  if (threads > 0) at::set_num_threads(threads);
}

c10::Device resolve_device(const std::string& device) {
  if (device == "cpu") return c10::Device(c10::kCPU);
  const bool cuda = torch::cuda::is_available();
  if (device == "auto") return cuda ? c10::Device(c10::kCUDA, 0) : c10::Device(c10::kCPU);
  if (device == "cuda") {
    FLAT_CHECK(cuda, "--device cuda: no CUDA device is available (use --device cpu or auto)");
    return c10::Device(c10::kCUDA, 0);
  }
  fail("--device '" + device + "': expected auto, cpu or cuda");
}

c10::ScalarType precision_dtype(const std::string& precision) {
  if (precision == "fp32") return c10::kFloat;
  if (precision == "bf16") return c10::kBFloat16;
  fail("--precision '" + precision + "': expected fp32 or bf16");
}

std::string stored_dtype_name(const std::string& store) {
  if (store == "fp32") return "float32";
  if (store == "bf16") return "bfloat16";
  if (store == "fp16") return "float16";
  fail("--store '" + store + "': expected fp32, bf16 or fp16");
}

int parse(CLI::App& app, int argc, char** argv) {
  rename_old_names(app, argc, argv);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version are "errors" with code 0; everything else is usage.
    return app.exit(e) == 0 ? kExitOk : kExitUsage;
  }
  restart_with_sleeping_openmp_threads(argv);
  return -1;
}

void restart_with_sleeping_openmp_threads(char** argv) {
  if (std::getenv("OMP_WAIT_POLICY") != nullptr || std::getenv("GOMP_SPINCOUNT") != nullptr) return;
  if (setenv("OMP_WAIT_POLICY", "PASSIVE", /*overwrite=*/0) != 0) return;
  std::fflush(nullptr);
  execv("/proc/self/exe", argv);
  // No restart (no /proc): libgomp's default waiting for this process; the
  // variable stays set for the processes it starts.
}

int run(const std::function<int()>& body) {
  try {
    return body();
  } catch (const UsageError& e) {
    std::cerr << e.what() << "\n";
    return kExitUsage;
  } catch (...) {
    return report_current_error();
  }
}

void start_logging(const std::string& level, const std::string& log_file) { setup_logging(level, log_file); }

uint64_t available_bytes(const c10::Device& device) {
#if FLAT_WITH_CUDA
  if (device.is_cuda()) {
    size_t free = 0, total = 0;
    int old = 0;
    if (cudaGetDevice(&old) != cudaSuccess) return 0;
    cudaSetDevice(device.has_index() ? device.index() : 0);
    const bool ok = cudaMemGetInfo(&free, &total) == cudaSuccess;
    cudaSetDevice(old);
    return ok ? uint64_t(free) : 0;
  }
#endif
  if (device.is_cuda()) return 0;
  std::ifstream in("/proc/meminfo");
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("MemAvailable:", 0) != 0) continue;
    std::istringstream ls(line.substr(13));
    uint64_t kib = 0;
    ls >> kib;
    return kib * 1024;
  }
  return 0;
}

std::string gib_text(double bytes) {
  char buf[64];
  const double gib = bytes / double(1ull << 30);
  if (gib >= 1.0 || !std::isfinite(gib)) {
    std::snprintf(buf, sizeof(buf), "%.1f GiB", gib);
  } else {
    std::snprintf(buf, sizeof(buf), "%.0f MiB", bytes / double(1ull << 20));
  }
  return buf;
}

void check_memory(double bytes, const std::string& what, const c10::Device& device) {
  const uint64_t avail = available_bytes(device);
  if (avail == 0) return;  // unknown: let the allocator decide
  if (!(bytes <= double(avail)))
    fail(what + " needs " + gib_text(bytes) + " on " + device.str() + " but " + gib_text(double(avail)) +
         " are available");
}

}  // namespace flat::cli
