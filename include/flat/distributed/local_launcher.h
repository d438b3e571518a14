// `flat_train --nproc N`: starts N worker processes on this host, each this
// same binary with the environment a torchrun-style launcher sets (RANK,
// LOCAL_RANK, WORLD_SIZE, LOCAL_WORLD_SIZE, MASTER_ADDR=127.0.0.1, MASTER_PORT
// a free port), and supervises them:
//
//   - SIGINT/SIGTERM to the launcher are forwarded to every worker (the
//     workers sit in a process group of their own, so a terminal's Ctrl-C
//     reaches them once, through the launcher);
//   - the first worker to fail (nonzero exit or a signal) is named with its
//     exit status or signal; the others get SIGTERM (and SIGCONT, should they
//     be stopped), a second SIGTERM after `failure_grace` (it ends a rank at
//     once: one blocked in a collective with the failed rank, say a GPU
//     stream waiting on NCCL, never sees the first), and SIGKILL after `grace`;
//   - a worker whose launcher dies gets SIGTERM from the kernel
//     (PR_SET_PDEATHSIG): it checkpoints and stops as if asked.
//
// Returns what the launcher exits with: 0 when every worker finished, 128 +
// signal when a forwarded signal stopped them, 1 when a worker failed.
#pragma once
#include <chrono>
#include <string>
#include <vector>

namespace flat::distributed {

struct LaunchOptions {
  int nproc = 1;
  std::string program;            // the workers' binary; "": this one (/proc/self/exe)
  std::vector<std::string> args;  // the workers' arguments (argv[1..], without --nproc)
  std::string master_addr = "127.0.0.1";
  int port = 0;  // 0: MASTER_PORT when set, else a free port picked here
  std::chrono::milliseconds failure_grace{10000};  // first -> second SIGTERM for the others after a failure
  std::chrono::milliseconds grace{30000};          // SIGTERM -> SIGKILL for the other workers after a failure
};

int launch_local_workers(const LaunchOptions& options);

// argv without `--name VALUE` / `--name=VALUE` (the workers must not launch again).
std::vector<std::string> drop_option(const std::vector<std::string>& args, const std::string& name);

}  // namespace flat::distributed
