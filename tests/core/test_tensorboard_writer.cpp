// TensorBoardWriter: CRC vectors, Events that decode back, and written files
// that parse as TFRecords. The decoder below is written independently of the
// writer's encoder, so a wrong field number or wire type shows up here.
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "flat/core/error.h"
#include "flat/core/tensorboard_writer.h"
#include "support/read_file.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using flat::tensorboard::crc32c;
using flat::tensorboard::masked_crc32c;

struct DecodedEvent {
  double wall_time = 0;
  int64_t step = 0;
  std::string file_version;
  std::vector<std::pair<std::string, float>> values;
};

// A tiny protobuf reader for the fields above; fails the test on anything else.
class Reader {
 public:
  explicit Reader(const std::string& bytes) : s_(bytes) {}
  bool done() const { return pos_ == s_.size(); }
  uint64_t varint() {
    uint64_t v = 0;
    for (int shift = 0;; shift += 7) {
      REQUIRE(pos_ < s_.size());
      REQUIRE(shift < 64);
      const auto byte = static_cast<uint8_t>(s_[pos_++]);
      v |= uint64_t(byte & 0x7F) << shift;
      if (!(byte & 0x80)) return v;
    }
  }
  uint64_t fixed(int bytes) {
    REQUIRE(pos_ + bytes <= s_.size());
    uint64_t v = 0;
    for (int i = 0; i < bytes; ++i) v |= uint64_t(static_cast<uint8_t>(s_[pos_++])) << (8 * i);
    return v;
  }
  std::string bytes() {
    const uint64_t n = varint();
    REQUIRE(pos_ + n <= s_.size());
    std::string out = s_.substr(pos_, n);
    pos_ += n;
    return out;
  }

 private:
  const std::string& s_;
  size_t pos_ = 0;
};

std::pair<std::string, float> decode_value(const std::string& bytes) {
  std::pair<std::string, float> out;
  Reader r(bytes);
  while (!r.done()) {
    const uint64_t key = r.varint();
    if (key == (1 << 3 | 2)) {
      out.first = r.bytes();
    } else if (key == (2 << 3 | 5)) {
      const auto bits = static_cast<uint32_t>(r.fixed(4));
      std::memcpy(&out.second, &bits, 4);
    } else {
      FAIL("Value: unexpected key " << key);
    }
  }
  return out;
}

DecodedEvent decode_event(const std::string& bytes) {
  DecodedEvent e;
  Reader r(bytes);
  while (!r.done()) {
    const uint64_t key = r.varint();
    if (key == (1 << 3 | 1)) {
      const uint64_t bits = r.fixed(8);
      std::memcpy(&e.wall_time, &bits, 8);
    } else if (key == (2 << 3 | 0)) {
      e.step = static_cast<int64_t>(r.varint());
    } else if (key == (3 << 3 | 2)) {
      e.file_version = r.bytes();
    } else if (key == (5 << 3 | 2)) {
      const std::string summary = r.bytes();
      Reader s(summary);
      while (!s.done()) {
        REQUIRE(s.varint() == (1 << 3 | 2));  // Summary.value
        e.values.push_back(decode_value(s.bytes()));
      }
    } else {
      FAIL("Event: unexpected key " << key);
    }
  }
  return e;
}

uint32_t le32(const std::string& s, size_t at) {
  uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v |= uint32_t(static_cast<uint8_t>(s[at + i])) << (8 * i);
  return v;
}

uint32_t masked(const std::string& s, size_t at, size_t n) {
  return masked_crc32c(reinterpret_cast<const uint8_t*>(s.data()) + at, n);
}

// Splits a file into TFRecord payloads, checking both CRCs of each record.
std::vector<std::string> read_records(const std::string& path) {
  const std::string file = flat::test::read_file(path);
  std::vector<std::string> records;
  size_t pos = 0;
  while (pos < file.size()) {
    REQUIRE(pos + 12 <= file.size());
    uint64_t length = 0;
    for (int i = 0; i < 8; ++i) length |= uint64_t(static_cast<uint8_t>(file[pos + i])) << (8 * i);
    CHECK(le32(file, pos + 8) == masked(file, pos, 8));
    pos += 12;
    REQUIRE(pos + length + 4 <= file.size());
    CHECK(le32(file, pos + length) == masked(file, pos, length));
    records.push_back(file.substr(pos, length));
    pos += length + 4;
  }
  return records;
}

}  // namespace

TEST_CASE("crc32c matches the RFC 3720 vectors", "[train][tensorboard]") {
  const std::string digits = "123456789";
  CHECK(crc32c(reinterpret_cast<const uint8_t*>(digits.data()), digits.size()) == 0xE3069283u);
  const std::vector<uint8_t> zeros(32, 0);
  CHECK(crc32c(zeros.data(), zeros.size()) == 0x8A9136AAu);
  const std::vector<uint8_t> ones(32, 0xFF);
  CHECK(crc32c(ones.data(), ones.size()) == 0x62A8AB43u);
  // The mask rotates right by 15 and adds a constant.
  const uint32_t crc = 0xE3069283u;
  CHECK(masked_crc32c(reinterpret_cast<const uint8_t*>(digits.data()), digits.size()) ==
        static_cast<uint32_t>(((crc >> 15) | (crc << 17)) + 0xa282ead8u));
}

TEST_CASE("a scalar Event decodes back to its inputs", "[train][tensorboard]") {
  const std::vector<std::pair<std::string, double>> values = {
      {"loss/total", 0.125}, {"lr", 3e-4}, {"psnr", 31.4159}, {"neg", -2.5}};
  const double wall_time = 1700000000.123456;
  for (int64_t step : {int64_t(0), int64_t(1), int64_t(300), int64_t(1) << 40, int64_t(-7)}) {
    const DecodedEvent e = decode_event(flat::tensorboard::encode_scalar_event(wall_time, step, values));
    CHECK(e.wall_time == wall_time);
    CHECK(e.step == step);
    CHECK(e.file_version.empty());
    REQUIRE(e.values.size() == values.size());
    for (size_t i = 0; i < values.size(); ++i) {
      CHECK(e.values[i].first == values[i].first);
      CHECK(e.values[i].second == static_cast<float>(values[i].second));
    }
  }
  // Non-finite values are written as is.
  const DecodedEvent e = decode_event(flat::tensorboard::encode_scalar_event(
      1.0, 5, {{"nan", std::numeric_limits<double>::quiet_NaN()}, {"inf", -HUGE_VAL}}));
  REQUIRE(e.values.size() == 2);
  CHECK(std::isnan(e.values[0].second));
  CHECK(e.values[1].second == -std::numeric_limits<float>::infinity());
}

TEST_CASE("a written event file is file_version then the scalars, in order", "[train][tensorboard]") {
  const auto dir = flat::test::scratch_dir("tensorboard_file") / "run" / "tb";  // parents are created
  std::string path;
  {
    flat::tensorboard::TensorBoardWriter tb(dir.string());
    path = tb.path();
    CHECK(fs::path(path).parent_path() == dir);
    CHECK(fs::path(path).filename().string().rfind("events.out.tfevents.", 0) == 0);
    tb.add_scalar("loss", 0.5, 10, 1000.0);
    tb.add_scalars({{"loss", 0.25}, {"lr", 1e-3}}, 20, 1001.0);
    tb.add_scalars({}, 25);  // writes nothing
    tb.add_scalar("psnr", 30.0, 30);  // wall time: now
    CHECK_THROWS_AS(tb.add_scalar("", 1.0, 40), flat::Error);
  }  // the destructor flushes
  const auto records = read_records(path);
  REQUIRE(records.size() == 4);

  const DecodedEvent version = decode_event(records[0]);
  CHECK(version.file_version == "brain.Event:2");
  CHECK(version.values.empty());
  CHECK(version.wall_time > 1.6e9);

  const DecodedEvent a = decode_event(records[1]), b = decode_event(records[2]), c = decode_event(records[3]);
  CHECK(a.step == 10);
  CHECK(a.wall_time == 1000.0);
  REQUIRE(a.values.size() == 1);
  CHECK(a.values[0] == std::make_pair(std::string("loss"), 0.5f));
  CHECK(b.step == 20);
  CHECK(b.wall_time == 1001.0);
  REQUIRE(b.values.size() == 2);
  CHECK(b.values[0] == std::make_pair(std::string("loss"), 0.25f));
  CHECK(b.values[1] == std::make_pair(std::string("lr"), 1e-3f));
  CHECK(c.step == 30);
  CHECK(c.wall_time >= version.wall_time);
  REQUIRE(c.values.size() == 1);
  CHECK(c.values[0] == std::make_pair(std::string("psnr"), 30.0f));
}

TEST_CASE("an unwritable folder throws flat::Error naming the path", "[train][tensorboard]") {
  const auto dir = flat::test::scratch_dir("tensorboard_unwritable");
  const fs::path blocker = dir / "not_a_folder";
  std::ofstream(blocker) << "a regular file";
  const std::string folder = (blocker / "tb").string();
  REQUIRE_THROWS_AS(flat::tensorboard::TensorBoardWriter(folder), flat::Error);
  REQUIRE_THROWS_WITH(flat::tensorboard::TensorBoardWriter(folder), FLAT_CONTAINS(folder));
}
