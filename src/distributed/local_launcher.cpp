#include "flat/distributed/local_launcher.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <thread>

#include <spdlog/spdlog.h>

#include "flat/core/error.h"

extern char** environ;

namespace flat::distributed {
namespace {

using Clock = std::chrono::steady_clock;

// A port nobody listens on now (the kernel's choice for port 0). Another
// process may take it before rank 0 binds it; rank 0 then fails to start and
// the launcher says so.
int free_port(const std::string& addr) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  FLAT_CHECK(fd >= 0, std::string("launcher: socket(): ") + std::strerror(errno));
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = 0;
  if (inet_pton(AF_INET, addr.c_str(), &a.sin_addr) != 1) a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof(a);
  const bool ok = bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0 &&
                  getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) == 0;
  const int err = errno;
  close(fd);
  FLAT_CHECK(ok, std::string("launcher: no free port on ") + addr + ": " + std::strerror(err));
  return ntohs(a.sin_port);
}

// "exited with status 1", "was killed by signal 9 (Killed)".
std::string describe(int status) {
  if (WIFEXITED(status)) return "exited with status " + std::to_string(WEXITSTATUS(status));
  if (WIFSIGNALED(status))
    return "was killed by signal " + std::to_string(WTERMSIG(status)) + " (" + strsignal(WTERMSIG(status)) + ")";
  return "ended with wait status " + std::to_string(status);
}

bool is_env(const char* entry, const char* name) {
  const size_t n = std::strlen(name);
  return std::strncmp(entry, name, n) == 0 && entry[n] == '=';
}

}  // namespace

std::vector<std::string> drop_option(const std::vector<std::string>& args, const std::string& name) {
  std::vector<std::string> out;
  for (size_t i = 0; i < args.size(); ++i) {
    if (args[i] == name) {
      ++i;  // and its value
      continue;
    }
    if (args[i].rfind(name + "=", 0) == 0) continue;
    out.push_back(args[i]);
  }
  return out;
}

int launch_local_workers(const LaunchOptions& o) {
  FLAT_CHECK(o.nproc >= 1, "launcher: --nproc must be at least 1, got " + std::to_string(o.nproc));
  const std::string exe =
      o.program.empty() ? std::filesystem::read_symlink("/proc/self/exe").string() : o.program;
  int port = o.port;
  if (port == 0) {
    const char* p = std::getenv("MASTER_PORT");
    port = p && *p ? std::atoi(p) : free_port(o.master_addr);
  }
  FLAT_CHECK(port > 0 && port < 65536, "launcher: MASTER_PORT " + std::to_string(port) + " is not a port");

  // Everything the children need is built before fork: after it, a child only
  // calls async-signal-safe functions until exec.
  static const char* kOwnVars[] = {"RANK",        "LOCAL_RANK",  "WORLD_SIZE", "LOCAL_WORLD_SIZE",
                                   "MASTER_ADDR", "MASTER_PORT", "GROUP_RANK", "ROLE_RANK"};
  std::vector<std::string> base_env;
  bool has_omp = false;
  for (char** e = environ; *e; ++e) {
    bool ours = false;
    for (const char* v : kOwnVars) ours = ours || is_env(*e, v);
    if (!ours) base_env.emplace_back(*e);
    has_omp = has_omp || is_env(*e, "OMP_NUM_THREADS");
  }
  // N workers on one host share its cores (torchrun sets OMP_NUM_THREADS too);
  // the config's `threads` still wins inside a worker.
  const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
  const int threads = std::max(1, int(cores) / o.nproc);
  if (!has_omp) base_env.push_back("OMP_NUM_THREADS=" + std::to_string(threads));
  std::vector<std::vector<std::string>> envs(size_t(o.nproc), base_env);
  for (int r = 0; r < o.nproc; ++r) {
    auto& env = envs[size_t(r)];
    for (const std::string& kv :
         {"RANK=" + std::to_string(r), "LOCAL_RANK=" + std::to_string(r), "WORLD_SIZE=" + std::to_string(o.nproc),
          "LOCAL_WORLD_SIZE=" + std::to_string(o.nproc), "MASTER_ADDR=" + o.master_addr,
          "MASTER_PORT=" + std::to_string(port)})
      env.push_back(kv);
  }
  std::vector<std::string> argv_store = {exe};
  argv_store.insert(argv_store.end(), o.args.begin(), o.args.end());
  std::vector<char*> argv;
  for (auto& a : argv_store) argv.push_back(a.data());
  argv.push_back(nullptr);
  std::vector<std::vector<char*>> envps(size_t(o.nproc));
  for (int r = 0; r < o.nproc; ++r) {
    for (auto& e : envs[size_t(r)]) envps[size_t(r)].push_back(e.data());
    envps[size_t(r)].push_back(nullptr);
  }

  // The signals the loop below waits for are blocked, so none is lost between waits.
  sigset_t waited, old_mask;
  sigemptyset(&waited);
  sigaddset(&waited, SIGINT);
  sigaddset(&waited, SIGTERM);
  sigaddset(&waited, SIGCHLD);
  sigprocmask(SIG_BLOCK, &waited, &old_mask);

  const pid_t launcher = getpid();
  std::vector<pid_t> pids(size_t(o.nproc), -1);
  pid_t group = 0;
  for (int r = 0; r < o.nproc; ++r) {
    const pid_t pid = fork();
    if (pid < 0) {
      const int err = errno;
      for (pid_t p : pids)
        if (p > 0) kill(p, SIGKILL);
      fail(std::string("launcher: fork() failed: ") + std::strerror(err));
    }
    if (pid == 0) {
      setpgid(0, group);                 // the workers' own group: a terminal's Ctrl-C reaches the launcher only
      prctl(PR_SET_PDEATHSIG, SIGTERM);  // launcher gone: checkpoint and stop
      if (getppid() != launcher) _exit(1);
      sigprocmask(SIG_SETMASK, &old_mask, nullptr);
      execve(exe.c_str(), argv.data(), envps[size_t(r)].data());
      const char msg[] = "flat_train launcher: execve of the worker failed\n";
      (void)!write(2, msg, sizeof(msg) - 1);
      _exit(127);
    }
    setpgid(pid, group);  // also here: whichever runs first
    if (group == 0) group = pid;
    pids[size_t(r)] = pid;
  }
  spdlog::info("launcher: {} workers (ranks 0-{}, pids {}-{}), MASTER_ADDR={} MASTER_PORT={}{}", o.nproc, o.nproc - 1,
               pids.front(), pids.back(), o.master_addr, port,
               has_omp ? "" : ", OMP_NUM_THREADS=" + std::to_string(threads));

  std::vector<int> status(size_t(o.nproc), 0);
  std::vector<bool> done(size_t(o.nproc), false);
  int running = o.nproc, forwarded = 0, failed_rank = -1;
  bool stopped = false;  // a worker ended with 128 + the forwarded signal
  Clock::time_point kill_at = Clock::time_point::max(), term_again_at = Clock::time_point::max();
  auto signal_running = [&](int sig) {
    for (int r = 0; r < o.nproc; ++r)
      if (!done[size_t(r)]) kill(pids[size_t(r)], sig);
  };
  while (running > 0) {
    const auto now = Clock::now();
    auto wait_for = std::chrono::milliseconds(500);
    if (term_again_at != Clock::time_point::max()) {
      if (now >= term_again_at) {
        spdlog::error("launcher: {} worker(s) still running {} s after rank {} failed (blocked in a collective with "
                      "it); ending them", running,
                      std::chrono::duration_cast<std::chrono::seconds>(o.failure_grace).count(), failed_rank);
        signal_running(SIGTERM);  // the second: the default action
        term_again_at = Clock::time_point::max();
      } else {
        wait_for = std::min(wait_for, std::chrono::duration_cast<std::chrono::milliseconds>(term_again_at - now) +
                                          std::chrono::milliseconds(1));
      }
    }
    if (kill_at != Clock::time_point::max()) {
      if (now >= kill_at) {
        spdlog::error("launcher: {} worker(s) still running {} s after SIGTERM; sending SIGKILL", running,
                      std::chrono::duration_cast<std::chrono::seconds>(o.grace).count());
        signal_running(SIGKILL);
        kill_at = Clock::time_point::max();
      } else {
        wait_for = std::min(wait_for, std::chrono::duration_cast<std::chrono::milliseconds>(kill_at - now) +
                                          std::chrono::milliseconds(1));
      }
    }
    timespec ts{wait_for.count() / 1000, (wait_for.count() % 1000) * 1000000};
    const int sig = sigtimedwait(&waited, nullptr, &ts);
    if (sig == SIGINT || sig == SIGTERM) {
      // A second signal is forwarded too: the workers then end at once, as one process would.
      spdlog::warn("launcher: {} received; forwarded to the {} running worker(s)", strsignal(sig), running);
      forwarded = sig;
      signal_running(sig);
    }
    int st = 0;
    pid_t pid;
    while ((pid = waitpid(-1, &st, WNOHANG)) > 0) {
      int r = 0;
      while (r < o.nproc && pids[size_t(r)] != pid) ++r;
      if (r == o.nproc) continue;
      done[size_t(r)] = true;
      status[size_t(r)] = st;
      --running;
      const bool stop_exit = forwarded && WIFEXITED(st) && WEXITSTATUS(st) == 128 + forwarded;
      stopped = stopped || stop_exit;
      const bool ok = stop_exit || (WIFEXITED(st) && WEXITSTATUS(st) == 0);
      if (ok || failed_rank >= 0) {
        if (!ok) spdlog::warn("launcher: rank {} (pid {}) {}", r, pid, describe(st));
        continue;
      }
      failed_rank = r;
      spdlog::error("launcher: rank {} (pid {}) {}; stopping the other {} worker(s)", r, pid, describe(st), running);
      signal_running(SIGTERM);
      signal_running(SIGCONT);  // a stopped worker must run to see it
      if (running > 0) {
        term_again_at = Clock::now() + std::min(o.failure_grace, o.grace);
        kill_at = Clock::now() + o.grace;
      }
    }
  }
  sigprocmask(SIG_SETMASK, &old_mask, nullptr);
  if (failed_rank >= 0) {
    spdlog::error("launcher: failed: rank {} {} (each rank's messages above say more)", failed_rank,
                  describe(status[size_t(failed_rank)]));
    return 1;
  }
  if (stopped) return 128 + forwarded;
  return 0;
}

}  // namespace flat::distributed
