// MP4 writer: frame count, size (odd sizes padded) and content read back with
// ffprobe/ffmpeg; errors name ffmpeg's status and stderr; no partial output.
#include <cstdlib>
#include <filesystem>
#include <map>
#include <sstream>

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/export/video_writer.h"
#include "support/process.h"
#include "test_support.h"

using flat::exporter::ffmpeg_available;
using flat::exporter::write_mp4;

namespace {

// K frames, frame k filled with a colour of its own.
torch::Tensor coloured_frames(int64_t k, int64_t h, int64_t w) {
  auto frames = torch::empty({k, 3, h, w});
  for (int64_t i = 0; i < k; ++i) {
    const double t = double(i) / double(k - 1);
    frames[i][0].fill_(0.1 + 0.8 * t);
    frames[i][1].fill_(0.9 - 0.8 * t);
    frames[i][2].fill_(0.5);
  }
  return frames;
}

int count_files(const std::filesystem::path& dir) {
  int n = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) n += e.is_regular_file() ? 1 : 0;
  return n;
}

}  // namespace

TEST_CASE("mp4: frames, padded size and colours survive the encoder", "[export][video]") {
  if (!ffmpeg_available()) FLAT_SKIP("no ffmpeg on PATH (Debian package ffmpeg)");
  auto dir = flat::test::scratch_dir("video_writer");
  const int64_t k = 5, h = 33, w = 47;  // odd: padded to 34 x 48
  const auto path = (dir / "clip.mp4").string();
  write_mp4(path, coloured_frames(k, h, w), 12.0);
  REQUIRE(std::filesystem::exists(path));
  CHECK(count_files(dir) == 1);  // no temp file or log left

  const std::string ffprobe = flat::test::find_program("ffprobe");
  if (ffprobe.empty()) {
    WARN("no ffprobe on PATH: frame count and size of the MP4 not checked");
    return;
  }
  const auto log = (dir / "ffprobe.txt").string();
  REQUIRE(flat::test::run_program({ffprobe, "-v", "error", "-count_frames", "-select_streams", "v:0", "-show_entries",
                                   "stream=codec_name,width,height,pix_fmt,nb_read_frames,avg_frame_rate", "-of",
                                   "default=noprint_wrappers=1", path},
                                  log, 60) == 0);
  std::map<std::string, std::string> info;
  std::istringstream lines(flat::test::read_file(log));
  for (std::string line; std::getline(lines, line);) {
    const auto eq = line.find('=');
    if (eq != std::string::npos) info[line.substr(0, eq)] = line.substr(eq + 1);
  }
  CHECK(info["codec_name"] == "h264");
  CHECK(info["pix_fmt"] == "yuv420p");
  CHECK(info["width"] == "48");
  CHECK(info["height"] == "34");
  CHECK(info["nb_read_frames"] == "5");
  CHECK(info["avg_frame_rate"] == "12/1");

  // Decode back to rgb24: each frame's mean colour is its own (order kept).
  const std::string ffmpeg = flat::test::find_program("ffmpeg");
  const auto raw = (dir / "decoded.rgb").string();
  REQUIRE(flat::test::run_program({ffmpeg, "-v", "error", "-i", path, "-f", "rawvideo", "-pix_fmt", "rgb24", raw},
                                  (dir / "decode.txt").string(), 60) == 0);
  const std::string bytes = flat::test::read_file(raw);
  REQUIRE(bytes.size() == size_t(k * 34 * 48 * 3));
  auto decoded = torch::from_blob(const_cast<char*>(bytes.data()), {k, 34, 48, 3}, torch::kUInt8)
                     .to(torch::kFloat)
                     .div(255)
                     .permute({0, 3, 1, 2});
  const auto want = coloured_frames(k, h, w).mean({2, 3});
  const auto got = decoded.narrow(2, 0, h).narrow(3, 0, w).mean({2, 3});
  CHECK((got - want).abs().max().item<double>() < 0.02);
}

TEST_CASE("mp4: a failing ffmpeg is reported with its status and stderr", "[export][video]") {
  auto dir = flat::test::scratch_dir("video_writer_fail");
  // A stand-in ffmpeg that reads nothing and fails: also checks that the
  // broken pipe does not kill the writer (SIGPIPE).
  const auto bin = dir / "bin";
  std::filesystem::create_directories(bin);
  const auto fake = (bin / "ffmpeg").string();
  {
    std::ofstream f(fake);
    f << "#!/bin/sh\necho 'fake ffmpeg: unknown encoder libx264' >&2\nexit 3\n";
  }
  std::filesystem::permissions(fake, std::filesystem::perms::owner_all);
  const char* old_path = std::getenv("PATH");
  const std::string saved = old_path ? old_path : "";
  setenv("PATH", bin.c_str(), 1);
  const auto out = (dir / "clip.mp4").string();
  std::string message;
  try {
    write_mp4(out, torch::rand({4, 3, 256, 256}), 24);  // 786 KB: more than a pipe holds
  } catch (const flat::Error& e) {
    message = e.what();
  }
  setenv("PATH", saved.c_str(), 1);
  CHECK(message.find("clip.mp4: ffmpeg exited with status 3") != std::string::npos);
  CHECK(message.find("fake ffmpeg: unknown encoder libx264") != std::string::npos);
  CHECK(!std::filesystem::exists(out));
  CHECK(count_files(dir) == 0);  // no temp file or log left
}

TEST_CASE("mp4: bad input is reported", "[export][video]") {
  auto dir = flat::test::scratch_dir("video_writer_errors");
  const auto out = (dir / "x.mp4").string();
  REQUIRE_THROWS_WITH(write_mp4(out, torch::rand({2, 4, 8, 8}), 24), FLAT_CONTAINS("(K,3,H,W)"));
  REQUIRE_THROWS_WITH(write_mp4(out, torch::rand({3, 8, 8}), 24), FLAT_CONTAINS("x.mp4: mp4 frames"));
  REQUIRE_THROWS_WITH(write_mp4(out, torch::rand({0, 3, 8, 8}), 24), FLAT_CONTAINS("at least one frame"));
  REQUIRE_THROWS_WITH(write_mp4(out, torch::rand({1, 3, 8, 8}), 0), FLAT_CONTAINS("fps"));
  auto nan = torch::rand({1, 3, 8, 8});
  nan[0][1][2][3] = std::numeric_limits<float>::quiet_NaN();
  REQUIRE_THROWS_WITH(write_mp4(out, nan, 24), FLAT_CONTAINS("mp4 frames"));
  CHECK(!std::filesystem::exists(out));
}
