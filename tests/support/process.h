// Child processes in tests, one posix_spawn for all: the project's own
// binaries (flat_train must survive a real SIGKILL and say things on stderr,
// which only a separate process shows) and external programs found on PATH
// (ffprobe, chromium, python3), each with an argument vector (no shell),
// output into a log file.
#pragma once
#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "support/read_file.h"

extern char** environ;

namespace flat::test {

inline std::string binary(const std::string& name) { return std::string(FLAT_BINARY_DIR) + "/" + name; }

struct Child {
  pid_t pid = -1;
  std::string log;
  bool own_group = false;  // leads a process group of its own (killed as a group)
};

// Starts argv[0] with argv, extra "NAME=value" environment entries, stdout and
// stderr into `log`. own_group: stdin from /dev/null and a process group of its
// own (programs that start helpers, such as chromium, are then killed whole).
inline Child spawn(const std::vector<std::string>& argv, const std::string& log,
                   const std::vector<std::string>& extra_env = {}, bool own_group = false) {
  std::vector<std::string> env_store;
  for (char** e = environ; *e; ++e) env_store.emplace_back(*e);
  for (const auto& e : extra_env) env_store.push_back(e);
  std::vector<char*> args, envp;
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  for (const auto& e : env_store) envp.push_back(const_cast<char*>(e.c_str()));
  envp.push_back(nullptr);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  if (own_group) posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&fa, 1, 2);
  posix_spawnattr_t attr;
  posix_spawnattr_init(&attr);
  if (own_group) {
    posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETPGROUP);
    posix_spawnattr_setpgroup(&attr, 0);
  }
  Child c;
  c.log = log;
  c.own_group = own_group;
  const int rc = posix_spawn(&c.pid, args[0], &fa, &attr, args.data(), envp.data());
  posix_spawn_file_actions_destroy(&fa);
  posix_spawnattr_destroy(&attr);
  if (rc != 0) c.pid = -1;
  return c;
}

// Waits; returns the exit code, or 128 + signal for a killed child.
inline int wait_for(const Child& c) {
  int status = 0;
  if (c.pid <= 0 || waitpid(c.pid, &status, 0) < 0) return -1;
  if (WIFEXITED(status)) return WEXITSTATUS(status);
  if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
  return -1;
}

// Waits up to `seconds` for `c`; the exit code (128 + signal when killed), or
// -2 after killing a child that overran (so that a hang fails, not blocks, the
// test; a child with its own group is killed with its whole group).
inline int wait_bounded(const Child& c, double seconds);

// True while `c` has not exited (does not reap it).
inline bool running(const Child& c) {
  siginfo_t info{};
  return waitid(P_PID, id_t(c.pid), &info, WEXITED | WNOHANG | WNOWAIT) == 0 && info.si_pid == 0;
}

inline int run(const std::vector<std::string>& argv, const std::string& log,
               const std::vector<std::string>& extra_env = {}) {
  return wait_for(spawn(argv, log, extra_env));
}

inline int64_t count_lines(const std::string& path) {
  std::ifstream in(path);
  int64_t n = 0;
  for (std::string line; std::getline(in, line);) n += line.empty() ? 0 : 1;
  return n;
}

// Polls `ready` every 20 ms for up to `seconds`; true when it held.
inline bool wait_until(const std::function<bool()>& ready, double seconds) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < end) {
    if (ready()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return ready();
}

inline int wait_bounded(const Child& c, double seconds) {
  int status = 0;
  const bool exited = wait_until([&] { return waitpid(c.pid, &status, WNOHANG) == c.pid; }, seconds);
  if (!exited) {
    kill(c.own_group ? -c.pid : c.pid, SIGKILL);
    waitpid(c.pid, &status, 0);
    return -2;
  }
  if (WIFEXITED(status)) return WEXITSTATUS(status);
  if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
  return -1;
}

// The first executable `name` on PATH, or "".
inline std::string find_program(const std::string& name) {
  const char* env = std::getenv("PATH");
  std::stringstream ss(env ? env : "/usr/bin:/bin");
  for (std::string dir; std::getline(ss, dir, ':');) {
    const std::string p = (dir.empty() ? "." : dir) + "/" + name;
    struct stat st;
    if (::stat(p.c_str(), &st) == 0 && S_ISREG(st.st_mode) && ::access(p.c_str(), X_OK) == 0) return p;
  }
  return {};
}

// Runs an external program (argv[0] a path) in a group of its own; returns the
// exit status, 128 + signal when killed, -1 when it could not start, and
// 128 + SIGKILL after killing the whole group at `timeout_s`.
inline int run_program(const std::vector<std::string>& argv, const std::string& log, int timeout_s,
                       const std::vector<std::string>& extra_env = {}) {
  const Child c = spawn(argv, log, extra_env, /*own_group=*/true);
  if (c.pid <= 0) return -1;
  const int rc = wait_bounded(c, timeout_s);
  return rc == -2 ? 128 + SIGKILL : rc;
}

}  // namespace flat::test
