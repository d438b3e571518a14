// flat_train end to end, as separate processes on tiny synthetic scenes made
// by flat_synth and flat_latents: it learns, it resumes exactly after SIGKILL
// (several kill points, one inside a checkpoint write), it survives NaN
// batches, and bad inputs end with a clear message and nothing lost.
#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <thread>

#include <nlohmann/json.hpp>

#include "cli/cli_fixtures.h"
#include "data/data_test_dirs.h"
#include "flat/core/tensor_io.h"
#include "support/process.h"
#include "test_support.h"
#include "train_fixtures.h"

namespace fs = std::filesystem;
using namespace flat::test;

namespace {

// flat_train on write_config(steps, extra) in a fresh folder `name`: the
// folder, the exit code and the log.
struct TinyRun {
  std::string dir;
  int rc = 0;
  std::string log;
};
TinyRun train_tiny(const std::string& name, int steps, const std::string& extra) {
  const std::string d = fresh_dir(name).string();
  const int rc = train({"--config", write_config(d, steps, extra)}, d + "/log.txt");
  return {d, rc, read_file(d + "/log.txt")};
}

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

// An 8-step run in `d` with `env` (a hook that raises `sig`) stops with 128 + sig
// after one checkpointed step, and its resume ends with the reference run's losses.
void check_one_step_then_resume(const std::string& d, const std::string& env, int sig) {
  const int rc = train({"--config", write_config(d, 8)}, d + "/log1.txt", {env});
  INFO(read_file(d + "/log1.txt"));
  CHECK(rc == 128 + sig);
  CHECK(fs::exists(d + "/run/checkpoints/step_00000001/trainer.json"));
  CHECK(rows(d + "/run").size() == 1);
  REQUIRE(train({"--resume", d + "/run"}, d + "/log2.txt") == 0);
  CHECK(losses(d + "/run") == losses(reference_run()));
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
  check_loss_fell(r, "rgb");
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
  std::vector<int64_t> reference_val_steps;
  for (const auto& r : rows(reference_run(), "val")) reference_val_steps.push_back(r.at("step").get<int64_t>());
  REQUIRE(reference_val_steps == std::vector<int64_t>{0, 4, 8});
  struct KillPoint {
    const char* name;
    int64_t after_rows;      // SIGKILL once train.jsonl has this many rows (0: use the env hook)
    const char* kill_in_checkpoint;
    const char* kill_in_validation = nullptr;
  };
  for (const auto& k : {KillPoint{"before the first checkpoint", 1, nullptr},
                        KillPoint{"between checkpoints", 3, nullptr},
                        KillPoint{"inside the write of checkpoint 4", 0, "4"},
                        KillPoint{"inside the validation of step 4", 0, nullptr, "4"},
                        KillPoint{"after the last step's rows", 8, nullptr}}) {
    SECTION(k.name) {
      const std::string d = fresh_dir("train_kill").string();
      const std::string cfg = write_config(d, 8);
      std::vector<std::string> env;
      if (k.kill_in_checkpoint) env.push_back(std::string("FLAT_TEST_KILL_IN_CHECKPOINT=") + k.kill_in_checkpoint);
      if (k.kill_in_validation) env.push_back(std::string("FLAT_TEST_SIGNAL_IN_VALIDATION=") + k.kill_in_validation);
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
      if (k.kill_in_validation) {
        CHECK(fs::exists(d + "/run/checkpoints/step_00000004/trainer.json"));  // killed after the checkpoint
        for (const auto& r : rows(d + "/run", "val")) CHECK(r.at("step").get<int64_t>() < 4);
      }
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
      // The validation history survives the kill: every row, once, with the
      // uninterrupted run's figures (the row due at the checkpoint resumed
      // from is recomputed from the same weights).
      std::vector<int64_t> val_steps;
      for (const auto& r : rows(d + "/run", "val")) val_steps.push_back(r.at("step").get<int64_t>());
      CHECK(val_steps == reference_val_steps);
      const auto val = rows(d + "/run", "val"), val_ref = rows(reference_run(), "val");
      for (size_t i = 0; i < std::min(val.size(), val_ref.size()); ++i)
        CHECK(val[i].at("val_psnr").dump() == val_ref[i].at("val_psnr").dump());
      // TensorBoard shows one run too: the earlier session's lost steps are dropped.
      const int tb = check_tensorboard(d + "/run", d + "/tb_check.txt");
      INFO(read_file(d + "/tb_check.txt"));
      CHECK(tb == 0);
      for (const auto& e : fs::directory_iterator(d + "/run/checkpoints"))
        CHECK(e.path().filename().string().rfind(".incomplete-", 0) != 0);
    }
  }
}

TEST_CASE("flat_train: SIGTERM or SIGHUP writes a checkpoint and exits 128 + signal; resume finishes", "[train]") {
  const int sig = GENERATE(SIGTERM, SIGHUP);
  INFO("signal " << sig);
  const std::string d = fresh_dir("train_sigterm").string();
  auto child = spawn({binary("flat_train"), "--config", write_config(d, 8)}, d + "/log1.txt");
  const std::string jsonl = d + "/run/metrics/train.jsonl";
  REQUIRE(wait_until([&] { return count_lines(jsonl) >= 3; }, 300));
  kill(child.pid, sig);
  const int rc = wait_for(child);
  const std::string log = read_file(d + "/log1.txt");
  INFO(log);
  if (rc == 0) SUCCEED("finished before the signal arrived");
  else {
    CHECK(rc == 128 + sig);
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

TEST_CASE("flat_train: a SIGTERM repeated within a second (coreutils timeout sends two) still checkpoints",
          "[train]") {
  const std::string d = fresh_dir("train_sigterm_twice").string();
  auto child = spawn({binary("flat_train"), "--config", write_config(d, 8)}, d + "/log1.txt");
  const std::string jsonl = d + "/run/metrics/train.jsonl";
  REQUIRE(wait_until([&] { return count_lines(jsonl) >= 3; }, 300));
  // As `timeout` does: the command, then its process group; 50 ms apart so
  // that the second is delivered after the first was handled, not merged.
  kill(child.pid, SIGTERM);
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  kill(child.pid, SIGTERM);
  const int rc = wait_for(child);
  const std::string log = read_file(d + "/log1.txt");
  INFO(log);
  if (rc == 0) {
    SUCCEED("finished before the signals arrived");
  } else {
    CHECK(rc == 128 + SIGTERM);
    CHECK(log.find("stopped by signal 15") != std::string::npos);
    bool checkpoint = false;
    for (const auto& e : fs::directory_iterator(d + "/run/checkpoints"))
      checkpoint |= fs::exists(e.path() / "trainer.json");
    CHECK(checkpoint);
  }
}

TEST_CASE("flat_train: SIGTERM or SIGHUP during start-up is honoured after one step; resume finishes", "[train]") {
  for (int sig : {SIGTERM, SIGHUP}) {
    INFO("signal " << sig);
    const std::string d = fresh_dir("train_signal_startup").string();
    check_one_step_then_resume(d, "FLAT_TEST_SIGNAL_IN_STARTUP=" + std::to_string(sig), sig);
  }
}

TEST_CASE("flat_train: SIGTERM during the step-0 validation is honoured after one step; resume finishes",
          "[train]") {
  const std::string d = fresh_dir("train_sigterm_validation").string();
  check_one_step_then_resume(d, "FLAT_TEST_SIGNAL_IN_VALIDATION=0:" + std::to_string(SIGTERM), SIGTERM);
}

TEST_CASE("flat_train: a NaN batch is skipped and counted; NaN in a row stops cleanly", "[train]") {
  {
    const auto [d, rc, log] = train_tiny("train_nan_once", 6, "debug: {nan_steps: [2]}\n");
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
    const auto [d, rc, log] =
        train_tiny("train_nan_repeated", 8, "debug: {nan_steps: [3, 4, 5]}\nnan_guard: {max_consecutive: 3}\n");
    INFO(log);
    CHECK(rc == 1);
    CHECK(log.find("3 consecutive steps had a non-finite loss") != std::string::npos);
    CHECK(log.find("step_00000002") != std::string::npos);  // names the last good checkpoint
    CHECK(log.find("done in") == std::string::npos);
    CHECK(fs::exists(d + "/run/checkpoints/step_00000002/trainer.json"));
    CHECK_FALSE(fs::exists(d + "/run/checkpoints/step_00000006"));
  }
}

TEST_CASE("flat_train: a session whose every step is non-finite exits 1 and writes no model", "[train]") {
  const auto [d, rc, log] =
      train_tiny("train_nan_all", 3, "debug: {nan_steps: [0, 1, 2]}\nnan_guard: {max_consecutive: 5}\n");
  INFO(log);
  CHECK(rc == 1);
  CHECK(log.find("every one of the 3 steps") != std::string::npos);
  CHECK_FALSE(fs::exists(d + "/run/model.safetensors"));
  CHECK(log.find("finished") == std::string::npos);
}

TEST_CASE("flat_train --overwrite: only a run folder, and only once the new run has loaded", "[train]") {
  const std::string d = fresh_dir("train_overwrite").string();
  SECTION("a folder of the user's own files is refused and left byte-identical") {
    const std::string cfg = write_config(d, 2);
    write_text(d + "/run/thesis.tex", "my thesis");
    write_text(d + "/run/data/table.csv", "1,2,3");
    write_text(d + "/run/config.yaml", "not ours: a config.yaml alone is not a run\n");
    const auto before = snapshot(d + "/run");
    const int rc = train({"--config", cfg, "--overwrite"}, d + "/log.txt");
    const std::string log = read_file(d + "/log.txt");
    INFO(log);
    CHECK(rc == 1);
    CHECK(log.find(d + "/run' is not a flat_train run folder") != std::string::npos);
    CHECK(snapshot(d + "/run") == before);
  }
  SECTION("a run that fails at start-up leaves the old run as it was; one that starts replaces it") {
    const std::string cfg = write_config(d, 2);
    REQUIRE(train({"--config", cfg}, d + "/log1.txt") == 0);
    const auto before = snapshot(d + "/run");
    REQUIRE(before.count("checkpoints/step_00000002/trainer.json"));
    const int rc = train({"--config", cfg, "--overwrite", "--set", "data.datasets=[{root: " + d + "/no_such_data}]"},
                         d + "/log2.txt");
    INFO(read_file(d + "/log2.txt"));
    CHECK(rc == 1);
    CHECK(read_file(d + "/log2.txt").find(d + "/no_such_data") != std::string::npos);
    CHECK(snapshot(d + "/run") == before);
    // A model that cannot load (another width from a missing checkpoint) fails after the data: still untouched.
    const int rc2 = train({"--config", cfg, "--overwrite", "--set", "init.from=checkpoint", "--set",
                           "init.path=" + d + "/no_such_run"},
                          d + "/log3.txt");
    CHECK(rc2 == 1);
    CHECK(snapshot(d + "/run") == before);
    // A good start replaces it whole: nothing of the old run stays.
    write_text(d + "/run/renders/stale.png", "old");
    REQUIRE(train({"--config", cfg, "--overwrite", "--set", "steps=1"}, d + "/log4.txt") == 0);
    CHECK_FALSE(fs::exists(d + "/run/renders/stale.png"));
    CHECK_FALSE(fs::exists(d + "/run/checkpoints/step_00000002"));
    CHECK(fs::exists(d + "/run/checkpoints/step_00000001/trainer.json"));
    CHECK(rows(d + "/run").size() == 1);
    for (const auto& e : fs::directory_iterator(d)) CHECK(e.path().filename().string().find(".old-") == std::string::npos);
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
  // The newest checkpoint broken three ways: --resume names it and why, sets
  // it aside for inspection and continues from the one before, exactly.
  for (const char* fault : {"truncated", "no trainer.json", "NaN weights"}) {
    SECTION(std::string("a newest checkpoint with ") + fault + ": resume falls back to the one before") {
      const std::string dir = d + "/fallback";
      const std::string run = dir + "/run";
      fs::create_directories(dir);
      fs::copy(reference_run(), run, fs::copy_options::recursive);
      const std::string ckpt = run + "/checkpoints/step_00000008";
      std::string victim = ckpt + "/model.safetensors", why;
      if (std::string(fault) == "truncated") {
        fs::resize_file(victim, fs::file_size(victim) / 2);
      } else if (std::string(fault) == "no trainer.json") {
        victim = ckpt + "/trainer.json";
        fs::remove(victim);
        why = "missing";
      } else {
        auto tensors = flat::load_safetensors(victim);
        auto t = tensors.begin()->second.clone();
        t.view(-1)[0] = NAN;
        tensors.begin()->second = t;
        flat::save_safetensors(victim, tensors);
        why = "non-finite";
      }
      const std::string victim_bytes = read_file(victim);
      const int rc = train({"--resume", run, "--set", "steps=10"}, dir + "/log.txt");
      const std::string log = read_file(dir + "/log.txt");
      INFO(log);
      CHECK(rc == 0);
      CHECK(log.find("skipped checkpoint " + ckpt) != std::string::npos);
      CHECK(log.find(victim) != std::string::npos);
      if (!why.empty()) CHECK(log.find(why) != std::string::npos);
      CHECK(log.find("resume: " + run + "/checkpoints/step_00000006 at step 6") != std::string::npos);
      // Set aside byte for byte; the run went on from step 6 exactly as the uninterrupted one.
      std::string aside;
      for (const auto& e : fs::directory_iterator(run + "/checkpoints"))
        if (e.path().filename().string().rfind("step_00000008.broken-", 0) == 0) aside = e.path().string();
      REQUIRE_FALSE(aside.empty());
      if (std::string(fault) != "no trainer.json")
        CHECK(read_file(aside + "/model.safetensors") == victim_bytes);
      auto got = losses(run);
      REQUIRE(got.size() == 10);
      got.resize(8);
      CHECK(got == losses(reference_run()));
      CHECK(fs::exists(run + "/checkpoints/step_00000010/trainer.json"));
    }
  }
  SECTION("every checkpoint broken: resume fails naming each, and moves nothing") {
    const std::string run = d + "/allbad/run";
    fs::create_directories(d + "/allbad");
    fs::copy(reference_run(), run, fs::copy_options::recursive);
    for (const char* step : {"6", "8"}) {
      const std::string f = run + "/checkpoints/step_0000000" + step + "/model.safetensors";
      fs::resize_file(f, fs::file_size(f) / 2);
    }
    const auto before = read_file(run + "/checkpoints/step_00000006/model.safetensors");
    const int rc = train({"--resume", run, "--set", "steps=10"}, d + "/allbad/log.txt");
    const std::string log = read_file(d + "/allbad/log.txt");
    INFO(log);
    CHECK(rc == 1);
    CHECK(log.find("no intact checkpoint") != std::string::npos);
    CHECK(log.find(run + "/checkpoints/step_00000006/model.safetensors") != std::string::npos);
    CHECK(log.find(run + "/checkpoints/step_00000008/model.safetensors") != std::string::npos);
    CHECK(read_file(run + "/checkpoints/step_00000006/model.safetensors") == before);
    CHECK(fs::exists(run + "/checkpoints/step_00000008"));
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
