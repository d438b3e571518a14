// flat_train --nproc's supervisor (local_launcher.h) with shell scripts as
// workers: the environment each rank gets, exit codes, and the end of a run
// whose survivor is blocked after a peer failed (it never acts on a SIGTERM).
#include <chrono>
#include <fstream>
#include <sstream>

#include "flat/distributed/local_launcher.h"
#include "test_support.h"

using flat::distributed::LaunchOptions;
using flat::distributed::launch_local_workers;

namespace {

LaunchOptions shell_workers(int nproc, const std::string& script) {
  LaunchOptions o;
  o.nproc = nproc;
  o.program = "/bin/sh";
  o.args = {"-c", script};
  return o;
}

}  // namespace

TEST_CASE("launcher: every rank gets its RANK, LOCAL_RANK, WORLD_SIZE and the same MASTER_PORT", "[distributed]") {
  const std::string dir = flat::test::scratch_dir("launcher_env").string();
  auto o = shell_workers(3, "echo \"$RANK $LOCAL_RANK $WORLD_SIZE $MASTER_ADDR $MASTER_PORT\" > " + dir + "/rank$RANK");
  o.port = 29999;
  REQUIRE(launch_local_workers(o) == 0);
  for (int r = 0; r < 3; ++r) {
    std::ifstream in(dir + "/rank" + std::to_string(r));
    std::stringstream text;
    text << in.rdbuf();
    CHECK(text.str() == std::to_string(r) + " " + std::to_string(r) + " 3 127.0.0.1 29999\n");
  }
}

TEST_CASE("launcher: a failed rank makes the launcher exit 1", "[distributed]") {
  CHECK(launch_local_workers(shell_workers(2, "[ \"$RANK\" = 1 ] && exit 3; exit 0")) == 1);
  CHECK(launch_local_workers(shell_workers(2, "exit 0")) == 0);
}

TEST_CASE("launcher: a survivor that ignores the first SIGTERM is ended by the second, long before SIGKILL",
          "[distributed]") {
  // Rank 0 stands for a rank whose GPU stream waits on an NCCL collective with
  // the dead rank: its handler takes the first SIGTERM, the loop never sees it.
  auto o = shell_workers(2,
                         "if [ \"$RANK\" = 1 ]; then sleep 0.3; exit 3; fi; "
                         "trap 'trap - TERM' TERM; while :; do sleep 0.05; done");
  o.failure_grace = std::chrono::milliseconds(1000);
  o.grace = std::chrono::milliseconds(30000);
  const auto t0 = std::chrono::steady_clock::now();
  CHECK(launch_local_workers(o) == 1);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("launcher: survivor ended %.2f s after start (failure 0.3 s, second SIGTERM after 1 s, SIGKILL 30 s)\n",
              seconds);
  CHECK(seconds > 1.2);
  CHECK(seconds < 15.0);
}
