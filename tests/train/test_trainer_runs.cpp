// flat_train end to end, as separate processes on tiny synthetic scenes made
// by flat_synth and flat_latents: it learns, it resumes exactly after SIGKILL
// (several kill points, one inside a checkpoint write), it survives NaN
// batches, and bad inputs end with a clear message and nothing lost.
#include <filesystem>
#include <fstream>
#include <map>

#include <nlohmann/json.hpp>

#include "data/data_test_dirs.h"
#include "process.h"
#include "test_support.h"
#include "train_fixtures.h"

namespace fs = std::filesystem;
using namespace flat::test;

namespace {

// A python3 with the tensorboard package ($FLAT_PYTHON, else the venv that
// scripts/install_deps.sh makes), or "" when there is none.
std::string tensorboard_python() {
  static std::string py = [] {
    const char* env = std::getenv("FLAT_PYTHON");
    const char* home = std::getenv("HOME");
    const std::string candidate = env ? env : std::string(home ? home : "") + "/.cache/flat/venv/bin/python3";
    if (!fs::exists(candidate)) return std::string();
    const std::string log = fresh_dir("tb_probe").string() + "/probe.txt";
    return run({candidate, "-c", "import tensorboard"}, log) == 0 ? candidate : std::string();
  }();
  return py;
}

// scripts/check_tensorboard.py on a run folder: 0 when the event files equal
// metrics/train.jsonl; skips (returns 0 with a warning) without tensorboard.
int check_tensorboard(const std::string& run_dir, const std::string& log) {
  const std::string py = tensorboard_python();
  if (py.empty()) {
    WARN("the tensorboard Python package is not installed: event files not checked");
    return 0;
  }
  return run({py, std::string(FLAT_SOURCE_DIR) + "/scripts/check_tensorboard.py", run_dir + "/tensorboard",
              run_dir + "/metrics/train.jsonl"},
             log);
}

// The uninterrupted 8-step run every resume is compared with.
const std::string& reference_run() {
  static std::string run_dir = [] {
    const std::string d = fresh_dir("train_reference").string();
    REQUIRE(train({"--config", write_config(d, 8)}, d + "/log.txt") == 0);
    return d + "/run";
  }();
  return run_dir;
}

}  // namespace

TEST_CASE("flat_train: a tiny run lowers its loss and writes a complete run folder", "[train]") {
  const std::string d = fresh_dir("train_learns").string();
  const int rc = train({"--config", write_config(d, 40), "--set", "checkpoint.every=20", "--set", "validation.every=40"},
                       d + "/log.txt");
  INFO(read_file(d + "/log.txt"));
  REQUIRE(rc == 0);
  auto r = rows(d + "/run");
  REQUIRE(r.size() == 40);
  double first = 0, last = 0;
  for (int i = 0; i < 5; ++i) first += r[size_t(i)].at("rgb").get<double>() / 5;
  for (int i = 35; i < 40; ++i) last += r[size_t(i)].at("rgb").get<double>() / 5;
  INFO("mean rgb loss, first 5 steps " << first << ", last 5 " << last);
  CHECK(last < 0.6 * first);
  for (const char* f : {"config.yaml", "logs/train.log", "metrics/val.jsonl", "model.safetensors",
                        "checkpoints/step_00000040/model.safetensors", "checkpoints/step_00000040/trainer.json"})
    CHECK(fs::exists(d + "/run/" + f));
  CHECK(rows(d + "/run", "val").size() == 2);  // before the first step and after the last
  bool tensorboard = false;
  for (const auto& e : fs::directory_iterator(d + "/run/tensorboard"))
    tensorboard = tensorboard || e.path().filename().string().rfind("events.out.tfevents.", 0) == 0;
  CHECK(tensorboard);
  CHECK(check_tensorboard(d + "/run", d + "/tb_check.txt") == 0);
  const std::string log = read_file(d + "/log.txt");
  CHECK(log.find("held-out PSNR") != std::string::npos);
  CHECK(log.find("ETA") != std::string::npos);
}

TEST_CASE("flat_train: killed with SIGKILL anywhere, --resume continues bit for bit", "[train]") {
  const auto reference = losses(reference_run());
  REQUIRE(reference.size() == 8);
  struct KillPoint {
    const char* name;
    int64_t after_rows;      // SIGKILL once train.jsonl has this many rows (0: use the env hook)
    const char* kill_in_checkpoint;
  };
  for (const auto& k : {KillPoint{"before the first checkpoint", 1, nullptr},
                        KillPoint{"between checkpoints", 3, nullptr},
                        KillPoint{"inside the write of checkpoint 4", 0, "4"},
                        KillPoint{"after the last step's rows", 8, nullptr}}) {
    SECTION(k.name) {
      const std::string d = fresh_dir("train_kill").string();
      const std::string cfg = write_config(d, 8);
      std::vector<std::string> env;
      if (k.kill_in_checkpoint) env.push_back(std::string("FLAT_TEST_KILL_IN_CHECKPOINT=") + k.kill_in_checkpoint);
      auto child = spawn({binary("flat_train"), "--config", cfg}, d + "/log1.txt", env);
      REQUIRE(child.pid > 0);
      if (k.after_rows > 0) {
        const std::string jsonl = d + "/run/metrics/train.jsonl";
        REQUIRE(wait_until([&] { return count_lines(jsonl) >= k.after_rows; }, 300));
        kill(child.pid, SIGKILL);
      }
      const int killed = wait_for(child);
      INFO(read_file(d + "/log1.txt"));
      // The last case may finish before the kill lands; every other must die by it.
      if (k.after_rows != 8) REQUIRE(killed == 128 + SIGKILL);
      if (k.kill_in_checkpoint) {
        bool incomplete = false;
        for (const auto& e : fs::directory_iterator(d + "/run/checkpoints"))
          incomplete = incomplete || e.path().filename().string().rfind(".incomplete-", 0) == 0;
        CHECK(incomplete);                                            // the write really was cut short
        CHECK_FALSE(fs::exists(d + "/run/checkpoints/step_00000004"));  // and left nothing that looks complete
      }
      const int rc = train({"--resume", d + "/run"}, d + "/log2.txt");
      INFO(read_file(d + "/log2.txt"));
      REQUIRE(rc == 0);
      CHECK(losses(d + "/run") == reference);
      // TensorBoard shows one run too: the earlier session's lost steps are dropped.
      const int tb = check_tensorboard(d + "/run", d + "/tb_check.txt");
      INFO(read_file(d + "/tb_check.txt"));
      CHECK(tb == 0);
      for (const auto& e : fs::directory_iterator(d + "/run/checkpoints"))
        CHECK(e.path().filename().string().rfind(".incomplete-", 0) != 0);
    }
  }
}

TEST_CASE("flat_train: SIGTERM writes a checkpoint and exits 143; resume finishes", "[train]") {
  const std::string d = fresh_dir("train_sigterm").string();
  auto child = spawn({binary("flat_train"), "--config", write_config(d, 8)}, d + "/log1.txt");
  const std::string jsonl = d + "/run/metrics/train.jsonl";
  REQUIRE(wait_until([&] { return count_lines(jsonl) >= 3; }, 300));
  kill(child.pid, SIGTERM);
  const int rc = wait_for(child);
  const std::string log = read_file(d + "/log1.txt");
  INFO(log);
  if (rc == 0) SUCCEED("finished before the signal arrived");
  else {
    CHECK(rc == 128 + SIGTERM);
    const int64_t done = count_lines(jsonl);
    char name[32];
    std::snprintf(name, sizeof(name), "step_%08lld", static_cast<long long>(done));
    CHECK(fs::exists(d + "/run/checkpoints/" + name + "/trainer.json"));
    CHECK(log.find("--resume") != std::string::npos);
    CHECK(log.find("done in") == std::string::npos);
    REQUIRE(train({"--resume", d + "/run"}, d + "/log2.txt") == 0);
    CHECK(losses(d + "/run") == losses(reference_run()));
  }
}

TEST_CASE("flat_train: a NaN batch is skipped and counted; NaN in a row stops cleanly", "[train]") {
  {
    const std::string d = fresh_dir("train_nan_once").string();
    const int rc = train({"--config", write_config(d, 6, "debug: {nan_steps: [2]}\n")}, d + "/log.txt");
    const std::string log = read_file(d + "/log.txt");
    INFO(log);
    REQUIRE(rc == 0);
    auto r = rows(d + "/run");
    REQUIRE(r.size() == 6);
    CHECK(r[2].at("skipped").get<double>() == 1.0);
    CHECK(r[3].at("skipped").get<double>() == 0.0);
    CHECK(log.find("step 2: non-finite loss") != std::string::npos);
    CHECK(log.find("1 skipped as non-finite") != std::string::npos);
    // Skipped steps leave the weights alone: the losses after it are finite.
    CHECK(std::isfinite(r[5].at("loss").get<double>()));
  }
  {
    const std::string d = fresh_dir("train_nan_repeated").string();
    const int rc = train({"--config", write_config(d, 8, "debug: {nan_steps: [3, 4, 5]}\nnan_guard: {max_consecutive: 3}\n")},
                         d + "/log.txt");
    const std::string log = read_file(d + "/log.txt");
    INFO(log);
    CHECK(rc == 1);
    CHECK(log.find("3 consecutive steps had a non-finite loss") != std::string::npos);
    CHECK(log.find("step_00000002") != std::string::npos);  // names the last good checkpoint
    CHECK(log.find("done in") == std::string::npos);
    CHECK(fs::exists(d + "/run/checkpoints/step_00000002/trainer.json"));
    CHECK_FALSE(fs::exists(d + "/run/checkpoints/step_00000006"));
  }
}

TEST_CASE("flat_train: bad inputs end with a clear error and exit 1, nothing lost", "[train]") {
  const std::string d = fresh_dir("train_bad").string();
  struct Case {
    const char* name;
    std::string extra;                // appended to the config
    std::vector<std::string> sets;    // --set overrides
    std::vector<std::string> expect;  // words of the message
  };
  const std::string& data = tiny_data();
  const std::vector<Case> cases = {
      {"missing dataset", "", {"data.datasets=[{root: " + d + "/no_such_data}]"}, {d + "/no_such_data", "does not exist"}},
      {"config key typo", "", {"optim.lrr=0.1"}, {"optim.lrr", "did you mean 'optim.lr'"}},
      {"wrong value type", "", {"steps=many"}, {"steps", "integer"}},
      {"stage file naming a missing checkpoint", "init: {from: checkpoint, path: " + d + "/no_such_run}\n", {},
       {d + "/no_such_run", "not found"}},
      {"checkpoint from a different width", "init: {from: checkpoint, path: " + reference_run() + "}\n",
       {"pipeline.model.vae.dim=8"}, {"pipeline.model.vae.dim: checkpoint 4, this config 8"}},
      {"LPIPS without weights", "", {"loss.lambda_perc=0.5"}, {"loss", "lpips_weights"}},
  };
  (void)data;
  for (size_t i = 0; i < cases.size(); ++i) {
    const auto& c = cases[i];
    SECTION(c.name) {
      const std::string dir = d + "/case" + std::to_string(i);
      fs::create_directories(dir);
      std::vector<std::string> args = {"--config", write_config(dir, 4, c.extra)};
      for (const auto& s : c.sets) args.insert(args.end(), {"--set", s});
      const int rc = train(args, dir + "/log.txt");
      const std::string log = read_file(dir + "/log.txt");
      INFO(log);
      CHECK(rc == 1);
      for (const auto& word : c.expect) CHECK(log.find(word) != std::string::npos);
      CHECK(log.find("Segmentation") == std::string::npos);
      CHECK_FALSE(fs::exists(dir + "/run"));  // a run that cannot start leaves no run folder behind
    }
  }
  SECTION("a truncated checkpoint") {
    const std::string run = d + "/trunc/run";
    fs::create_directories(d + "/trunc");
    fs::copy(reference_run(), run, fs::copy_options::recursive);
    const std::string victim = run + "/checkpoints/step_00000008/model.safetensors";
    const auto size = fs::file_size(victim);
    fs::resize_file(victim, size / 2);
    const std::string config_before = read_file(run + "/config.yaml");
    const auto older = run + "/checkpoints/step_00000006/model.safetensors";
    const std::string older_before = read_file(older);
    const int rc = train({"--resume", run, "--set", "steps=10"}, d + "/trunc/log.txt");
    const std::string log = read_file(d + "/trunc/log.txt");
    INFO(log);
    CHECK(rc == 1);
    CHECK(log.find(victim) != std::string::npos);
    CHECK(read_file(older) == older_before);
    CHECK(fs::file_size(victim) == size / 2);  // left for the user to inspect, not replaced
    (void)config_before;
  }
  SECTION("a new run into a folder that holds one") {
    const std::string dir = d + "/exists";
    fs::create_directories(dir);
    const std::string cfg = write_config(dir, 2);
    REQUIRE(train({"--config", cfg}, dir + "/log1.txt") == 0);
    const std::string metrics_before = read_file(dir + "/run/metrics/train.jsonl");
    const int rc = train({"--config", cfg}, dir + "/log2.txt");
    const std::string log = read_file(dir + "/log2.txt");
    INFO(log);
    CHECK(rc == 1);
    CHECK(log.find("--resume") != std::string::npos);
    CHECK(read_file(dir + "/run/metrics/train.jsonl") == metrics_before);
  }
  SECTION("usage errors exit 2") {
    CHECK(train({}, d + "/usage1.txt") == 2);
    CHECK(train({"--no-such-flag"}, d + "/usage2.txt") == 2);
    CHECK(train({"--resume", d, "--overwrite"}, d + "/usage3.txt") == 2);
  }
}
