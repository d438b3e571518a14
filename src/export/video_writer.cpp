// MP4 through the ffmpeg program: raw rgb24 frames on its stdin, its stderr
// into a log beside the temp file (read back only when it fails).
#include "flat/export/video_writer.h"

#include <fcntl.h>
#include <pthread.h>
#include <signal.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <vector>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "flat/core/shape.h"

extern char** environ;

namespace flat::exporter {
namespace {

// The first executable regular file `name` in $PATH, or "".
std::string find_on_path(const std::string& name) {
  const char* env = std::getenv("PATH");
  std::string path = env ? env : "/usr/local/bin:/usr/bin:/bin";
  std::stringstream ss(path);
  for (std::string dir; std::getline(ss, dir, ':');) {
    const std::string candidate = (dir.empty() ? std::string(".") : dir) + "/" + name;
    struct stat st;
    if (::stat(candidate.c_str(), &st) == 0 && S_ISREG(st.st_mode) && ::access(candidate.c_str(), X_OK) == 0)
      return candidate;
  }
  return {};
}

std::string tail_of_file(const std::string& path, size_t max_chars) {
  std::ifstream in(path, std::ios::binary);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  while (!text.empty() && (text.back() == '\n' || text.back() == '\r')) text.pop_back();
  if (text.size() > max_chars) text = "..." + text.substr(text.size() - max_chars);
  return text.empty() ? "(no output on stderr)" : text;
}

// Writes all bytes to fd with SIGPIPE blocked in this thread, so that an
// ffmpeg that exits early gives EPIPE here instead of killing the process.
// Returns 0 or the errno of the failed write.
int write_all_no_sigpipe(int fd, const uint8_t* data, size_t size) {
  sigset_t pipe_set, old;
  sigemptyset(&pipe_set);
  sigaddset(&pipe_set, SIGPIPE);
  pthread_sigmask(SIG_BLOCK, &pipe_set, &old);
  int err = 0;
  while (size > 0) {
    const ssize_t w = ::write(fd, data, size);
    if (w < 0) {
      if (errno == EINTR) continue;
      err = errno;
      break;
    }
    data += w;
    size -= size_t(w);
  }
  if (err == EPIPE && !sigismember(&old, SIGPIPE)) {
    // Swallow the SIGPIPE now pending on this thread before unblocking it.
    const timespec zero{0, 0};
    while (sigtimedwait(&pipe_set, nullptr, &zero) < 0 && errno == EINTR) {
    }
  }
  pthread_sigmask(SIG_SETMASK, &old, nullptr);
  return err;
}

}  // namespace

bool ffmpeg_available() { return !find_on_path("ffmpeg").empty(); }

void write_mp4(const std::string& path, const at::Tensor& frames, double fps) {
  const std::string what = path + ": mp4 frames";
  check_shape(frames, {-1, 3, -1, -1}, what, "(K,3,H,W)");
  const int64_t k = frames.size(0), h = frames.size(2), w = frames.size(3);
  FLAT_CHECK(k >= 1 && h >= 1 && w >= 1, what + ": need at least one frame of at least 1x1, got " + shape_str(frames));
  FLAT_CHECK(frames.is_floating_point(), what + ": must be floating point in [0,1]");
  check_finite(frames, what);
  FLAT_CHECK(std::isfinite(fps) && fps > 0, path + ": mp4 fps must be > 0, got " + std::to_string(fps));
  const std::string ffmpeg = find_on_path("ffmpeg");
  FLAT_CHECK(!ffmpeg.empty(), path + ": cannot write mp4: no ffmpeg on PATH (Debian package ffmpeg)");

  // (K,3,H,W) [0,1] -> (K,H',W',3) bytes, H' and W' even (yuv420p halves both).
  at::Tensor x = frames.detach().to(at::kCPU, at::kFloat).clamp(0, 1).mul(255).round().to(at::kByte);
  if (h % 2) x = at::cat({x, x.narrow(2, h - 1, 1)}, 2);
  if (w % 2) x = at::cat({x, x.narrow(3, w - 1, 1)}, 3);
  x = x.permute({0, 2, 3, 1}).contiguous();
  const int64_t he = x.size(1), we = x.size(2);

  AtomicFile file(path, ".mp4");  // the temp name keeps the extension ffmpeg looks at
  const std::string log = file.temp_path() + ".log";
  struct RemoveLog {
    std::string p;
    ~RemoveLog() { std::remove(p.c_str()); }
  } remove_log{log};

  std::ostringstream rate;
  rate.precision(12);
  rate << fps;
  const std::vector<std::string> args = {
      ffmpeg, "-hide_banner", "-nostats", "-loglevel", "error", "-y",
      "-f", "rawvideo", "-pix_fmt", "rgb24", "-video_size", std::to_string(we) + "x" + std::to_string(he),
      "-framerate", rate.str(), "-i", "pipe:0",
      "-an", "-c:v", "libx264", "-pix_fmt", "yuv420p", "-movflags", "+faststart", "-f", "mp4", file.temp_path()};
  std::vector<char*> argv;
  for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);

  int fds[2];
  FLAT_CHECK(::pipe2(fds, O_CLOEXEC) == 0, path + ": cannot create a pipe to ffmpeg: " + std::strerror(errno));
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_adddup2(&fa, fds[0], 0);  // the dup is not close-on-exec; both pipe ends are
  posix_spawn_file_actions_addopen(&fa, 1, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_addopen(&fa, 2, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  pid_t pid = -1;
  const int spawn_rc = posix_spawn(&pid, ffmpeg.c_str(), &fa, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&fa);
  ::close(fds[0]);
  if (spawn_rc != 0) {
    ::close(fds[1]);
    fail(path + ": cannot start " + ffmpeg + ": " + std::strerror(spawn_rc));
  }
  const int write_err = write_all_no_sigpipe(fds[1], x.data_ptr<uint8_t>(), size_t(x.numel()));
  ::close(fds[1]);  // end of input: ffmpeg finishes the file
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    const std::string how = WIFEXITED(status) ? "exited with status " + std::to_string(WEXITSTATUS(status))
                                              : "was killed by signal " + std::to_string(WTERMSIG(status));
    fail(path + ": ffmpeg " + how + ": " + tail_of_file(log, 2000));
  }
  FLAT_CHECK(write_err == 0, path + ": writing frames to ffmpeg failed: " + std::strerror(write_err) + "; ffmpeg said: " +
                                 tail_of_file(log, 2000));
  file.commit();
}

}  // namespace flat::exporter
