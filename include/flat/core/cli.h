// The command-line vocabulary every FLAT tool shares (docs/cli.md; one
// meaning per flag name, docs/cli_vocabulary.txt): --version,
// --log-level, --device auto|cpu|cuda, --precision fp32|bf16, --store
// fp32|bf16|fp16, the exit codes, the log file beside a tool's outputs, and
// the memory check that refuses a request before anything is allocated.
// Tools add their own options and call these, so a flag means one thing
// everywhere.
#pragma once
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <c10/core/Device.h>
#include <c10/core/ScalarType.h>

namespace flat::cli {

// Exit codes of every tool: 0 ok, 1 runtime error (the message names the
// file, key or shape), 2 usage error (a bad or missing flag).
inline constexpr int kExitOk = 0;
inline constexpr int kExitRuntime = 1;
inline constexpr int kExitUsage = 2;

inline constexpr const char* kVersion = "0.1.0";

// A usage error found after parsing (two flags that contradict each other):
// run() maps it to exit code 2.
class UsageError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// --version ("<tool> 0.1.0") and --log-level trace|debug|info|warn|error;
// every option's default is shown in --help from here on.
void add_common(CLI::App& app, const std::string& tool, std::string& log_level);

// --device auto|cpu|cuda (auto = cuda when present), --precision fp32|bf16
// (compute dtype), --store fp32|bf16|fp16 (stored dtype).
CLI::Option* add_device(CLI::App& app, std::string& device);
CLI::Option* add_precision(CLI::App& app, std::string& precision);
CLI::Option* add_store(CLI::App& app, std::string& store);
// --threads N: CPU threads for the tool's tensor work (0: libtorch's default,
// every core). apply_threads sets them; tools running side by side should
// share the cores between them.
CLI::Option* add_threads(CLI::App& app, int& threads);
// --window-fn flat|ts: the rasterizer's window function (flat: the paper's,
// ts: Triangle Splatting's). --window is a window of frames, never this.
CLI::Option* add_window_fn(CLI::App& app, std::string& window_fn);
void apply_threads(int threads);

// Old spellings of flags (docs/cli_vocabulary.txt): hidden from --help, still
// read. parse() rewrites `old_name` on this app (or subcommand) to `new_name`
// in argv before CLI11 sees it, and warns on stderr "flat_render: --window is
// an old name; use --window-fn". argv is rewritten in place, so the OpenMP
// restart and flat_train's --nproc workers get the new name (and no second
// warning).
void add_old_name(CLI::App& app, const std::string& old_name, const std::string& new_name);
// What parse() does first; flat_bench, which parses inside run(), calls it itself.
void rename_old_names(const CLI::App& app, int argc, char** argv);

// --set KEY=VALUE, repeatable: a config key by its full path, as flat_train
// takes it (pipeline.prune_opacity=0.4) in every tool. `example` is shown in --help.
CLI::Option* add_set(CLI::App& app, std::vector<std::string>& overrides, const std::string& example);
// A --size HxW option's value into height and width (left as they are when
// `text` is empty); any other text is a UsageError of `tool`.
void parse_size_option(const std::string& text, int64_t& height, int64_t& width, const std::string& tool);

// The --set overrides of a tool that reads one section of the training config
// (flat_eval, flat_infer: `pipeline`), relative to that section:
// "pipeline.prune_opacity=0.4" -> "prune_opacity=0.4". A key without the
// prefix whose first name is a key of the section (its defaults as YAML,
// `section_yaml`) is the old relative spelling: kept, with a warning that gives
// the full path. Any other key (data.height=50) is a UsageError naming it.
std::vector<std::string> section_overrides(const std::vector<std::string>& overrides, const std::string& section,
                                           const std::string& section_yaml, const std::string& tool);

// "auto" -> cuda when a CUDA device is present, else cpu; "cuda" without one
// is a flat::Error that says so.
c10::Device resolve_device(const std::string& device);
c10::ScalarType precision_dtype(const std::string& precision);  // fp32 | bf16
// The store flag's name as files name it: fp32 -> float32, bf16 -> bfloat16, fp16 -> float16.
std::string stored_dtype_name(const std::string& store);

// Parses argv (old flag names first, see add_old_name). Returns -1 to go on; otherwise the exit code to return at once
// (0 after --help or --version, 2 for a usage error, with CLI11's message).
// Going on, it first calls restart_with_sleeping_openmp_threads(argv).
int parse(CLI::App& app, int argc, char** argv);

// OpenMP threads that wait for work should sleep, not spin. libgomp spins
// ~300,000 times by default before it sleeps; two tools side by side, each
// with a team of every core, then spin against each other, and ran 20-80x
// slower on the 16-core GPU machine (issue #30, docs/benchmarks.md "CPU tools
// side by side"). libgomp reads OMP_WAIT_POLICY once, as it loads, before
// main(), and a process cannot change it later: so when the environment
// chooses no policy (neither OMP_WAIT_POLICY nor GOMP_SPINCOUNT is set), this
// sets OMP_WAIT_POLICY=PASSIVE and restarts the program in place (execv of
// /proc/self/exe: same pid, same arguments; one more start-up, ~0.6 s). Call
// it after parsing and before any work; the restarted process finds the
// variable set and goes on. A user's own setting is kept.
void restart_with_sleeping_openmp_threads(char** argv);

// Runs a tool's body: its return value, 2 for a UsageError, 1 (and the
// message through spdlog) for any other exception.
int run(const std::function<int()>& body);

// Console logging at `level`, plus `log_file` when given (appended; its
// folder is created). Tools put it beside their outputs.
void start_logging(const std::string& level, const std::string& log_file = "");

// Bytes the device can still give: CUDA free memory, or the host's
// MemAvailable (0 when unknown).
uint64_t available_bytes(const c10::Device& device);
// Throws flat::Error "<what> needs 12.3 GiB on cpu but 7.1 GiB are available"
// when `bytes` exceed what `device` can give (nothing when unknown). Call it
// before the allocation, with the request's size.
void check_memory(double bytes, const std::string& what, const c10::Device& device);
std::string gib_text(double bytes);  // "12.3 GiB" (or "512 MiB")

}  // namespace flat::cli
