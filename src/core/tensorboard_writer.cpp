// TFRecord framing + the few protobuf fields of a scalar Event, encoded by
// hand (see the header for why and for the layout).
#include "flat/core/tensorboard_writer.h"

#include <unistd.h>

#include <array>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>

#include "flat/core/error.h"

namespace flat::tensorboard {
namespace {

namespace fs = std::filesystem;

// Protobuf wire types.
constexpr uint32_t kVarint = 0, kFixed64 = 1, kLengthDelimited = 2, kFixed32 = 5;

void put_varint(std::string& out, uint64_t v) {
  while (v >= 0x80) {
    out.push_back(static_cast<char>((v & 0x7F) | 0x80));
    v >>= 7;
  }
  out.push_back(static_cast<char>(v));
}

void put_key(std::string& out, uint32_t field, uint32_t wire_type) { put_varint(out, (field << 3) | wire_type); }

// Little-endian whatever the host order.
void put_le(std::string& out, uint64_t v, int bytes) {
  for (int i = 0; i < bytes; ++i) out.push_back(static_cast<char>((v >> (8 * i)) & 0xFF));
}

void put_double(std::string& out, uint32_t field, double v) {
  uint64_t bits;
  std::memcpy(&bits, &v, sizeof bits);
  put_key(out, field, kFixed64);
  put_le(out, bits, 8);
}

void put_float(std::string& out, uint32_t field, float v) {
  uint32_t bits;
  std::memcpy(&bits, &v, sizeof bits);
  put_key(out, field, kFixed32);
  put_le(out, bits, 4);
}

void put_bytes(std::string& out, uint32_t field, const std::string& bytes) {
  put_key(out, field, kLengthDelimited);
  put_varint(out, bytes.size());
  out += bytes;
}

// Event fields 1 and 2; the caller appends file_version (3) or summary (5).
std::string event_head(double wall_time, int64_t step) {
  std::string event;
  put_double(event, 1, wall_time);
  put_key(event, 2, kVarint);
  put_varint(event, static_cast<uint64_t>(step));  // negative steps: 10-byte two's complement, as protobuf does
  return event;
}

double now_seconds() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

std::string hostname() {
  char name[256] = {};
  if (::gethostname(name, sizeof name - 1) != 0 || name[0] == '\0') return "localhost";
  return name;
}

}  // namespace

uint32_t crc32c(const uint8_t* data, size_t n) {
  static const std::array<uint32_t, 256> table = [] {
    std::array<uint32_t, 256> t{};
    for (uint32_t i = 0; i < 256; ++i) {
      uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c & 1) ? (c >> 1) ^ 0x82F63B78u : c >> 1;  // reflected Castagnoli polynomial
      t[i] = c;
    }
    return t;
  }();
  uint32_t crc = 0xFFFFFFFFu;
  for (size_t i = 0; i < n; ++i) crc = table[(crc ^ data[i]) & 0xFF] ^ (crc >> 8);
  return crc ^ 0xFFFFFFFFu;
}

uint32_t masked_crc32c(const uint8_t* data, size_t n) {
  const uint32_t crc = crc32c(data, n);
  return ((crc >> 15) | (crc << 17)) + 0xa282ead8u;
}

std::string encode_scalar_event(double wall_time, int64_t step,
                                const std::vector<std::pair<std::string, double>>& values) {
  std::string summary;
  for (const auto& [tag, value] : values) {
    std::string v;
    put_bytes(v, 1, tag);
    put_float(v, 2, static_cast<float>(value));  // NaN / inf pass through
    put_bytes(summary, 1, v);
  }
  std::string event = event_head(wall_time, step);
  put_bytes(event, 5, summary);
  return event;
}

std::string encode_session_start_event(double wall_time, int64_t step) {
  std::string session_log;
  put_key(session_log, 1, kVarint);  // SessionLog.status
  put_varint(session_log, 1);        // START
  std::string event = event_head(wall_time, step);
  put_bytes(event, 7, session_log);  // Event.session_log (6 is the deprecated log_message)
  return event;
}

TensorBoardWriter::TensorBoardWriter(const std::string& folder) {
  std::error_code ec;
  fs::create_directories(folder, ec);
  if (ec) fail("tensorboard: cannot create folder " + folder + ": " + ec.message());
  // TensorBoard reads a folder's files in name order: seconds and microseconds,
  // zero-padded, so that a resumed session's file comes after the earlier one
  // even within the same second (its SessionLog START must be read last).
  const double now = now_seconds();
  char stamp[48];
  std::snprintf(stamp, sizeof(stamp), "%010lld.%06lld", static_cast<long long>(now),
                static_cast<long long>((now - std::floor(now)) * 1e6));
  path_ = (fs::path(folder) / ("events.out.tfevents." + std::string(stamp) + "." + hostname() + "." +
                               std::to_string(::getpid())))
              .string();
  out_.open(path_, std::ios::binary | std::ios::app);
  if (!out_) fail("tensorboard: cannot open " + path_ + ": " + std::strerror(errno));
  std::string version = event_head(now_seconds(), 0);
  put_bytes(version, 3, "brain.Event:2");
  write_record(version);
  flush();  // the file is a valid (empty) run from the start
}

TensorBoardWriter::~TensorBoardWriter() {
  if (out_.is_open()) out_.flush();  // no throw from a destructor
}

void TensorBoardWriter::add_scalar(const std::string& tag, double value, int64_t step, double wall_time_seconds) {
  add_scalars({{tag, value}}, step, wall_time_seconds);
}

void TensorBoardWriter::add_scalars(const std::vector<std::pair<std::string, double>>& tagged, int64_t step,
                                    double wall_time_seconds) {
  if (tagged.empty()) return;
  for (const auto& item : tagged) FLAT_CHECK(!item.first.empty(), "tensorboard: empty tag for " + path_);
  const double wall_time = wall_time_seconds < 0 ? now_seconds() : wall_time_seconds;
  write_record(encode_scalar_event(wall_time, step, tagged));
}

void TensorBoardWriter::add_session_start(int64_t step, double wall_time_seconds) {
  write_record(encode_session_start_event(wall_time_seconds < 0 ? now_seconds() : wall_time_seconds, step));
}

void TensorBoardWriter::flush() {
  out_.flush();
  if (!out_) fail("tensorboard: cannot flush " + path_);
}

void TensorBoardWriter::write_record(const std::string& data) {
  std::string header;
  put_le(header, data.size(), 8);
  const uint32_t length_crc = masked_crc32c(reinterpret_cast<const uint8_t*>(header.data()), 8);
  put_le(header, length_crc, 4);
  std::string footer;
  put_le(footer, masked_crc32c(reinterpret_cast<const uint8_t*>(data.data()), data.size()), 4);
  out_ << header << data << footer;
  if (!out_) fail("tensorboard: cannot write " + path_);
}

}  // namespace flat::tensorboard
