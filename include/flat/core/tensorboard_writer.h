// TensorBoard scalar logging: writes an event file that `tensorboard --logdir`
// reads (loss terms, learning rate, PSNR... against the step).
//
// A file format, not training logic, so it lives in core (the trainer's
// metrics_log writes through it). Hand-encoded on purpose: the GPU machine has
// no protobuf or crc32c development packages and cannot install any; Debian's
// libprotobuf would still need TensorFlow's event.proto / summary.proto, which
// no Debian package ships, compiled into the build; and a scalar event is only
// a few protobuf fields in a TFRecord frame:
//   record = uint64 length (LE) | uint32 masked_crc32c(length bytes) | data | uint32 masked_crc32c(data)
//   Event   { 1: double wall_time; 2: int64 step; 3: string file_version; 5: Summary summary; }
//   Summary { 1: repeated Value value; }
//   Value   { 1: string tag; 2: float simple_value; }
// Values are stored as float32 (TensorBoard's simple_value). A non-finite
// value is written as is: TensorBoard shows NaN / inf at that step, which is
// what a diverging run should look like.
#pragma once
#include <cstddef>
#include <cstdint>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

namespace flat::tensorboard {

class TensorBoardWriter {
 public:
  // Creates `folder` (and parents) and opens, in append mode,
  // <folder>/events.out.tfevents.<unix seconds>.<hostname>.<pid>; writes the
  // file_version record ("brain.Event:2") first. Throws flat::Error naming the
  // path on any IO failure (here and in every later call).
  explicit TensorBoardWriter(const std::string& folder);
  ~TensorBoardWriter();  // flushes; never throws
  TensorBoardWriter(const TensorBoardWriter&) = delete;
  TensorBoardWriter& operator=(const TensorBoardWriter&) = delete;

  // wall_time_seconds < 0: now. Tags must be non-empty.
  void add_scalar(const std::string& tag, double value, int64_t step, double wall_time_seconds = -1);
  // One Event holding several values (one step of a run's metrics); an empty list writes nothing.
  void add_scalars(const std::vector<std::pair<std::string, double>>& tagged, int64_t step,
                   double wall_time_seconds = -1);
  // A SessionLog START event at `step`: TensorBoard then drops every value of
  // this run folder at or after `step` that an earlier session wrote (a
  // resumed run after a crash rewrites those steps).
  void add_session_start(int64_t step, double wall_time_seconds = -1);
  void flush();
  const std::string& path() const { return path_; }

 private:
  void write_record(const std::string& data);

  std::string path_;
  std::ofstream out_;
};

// Exposed for tests.
uint32_t crc32c(const uint8_t* data, size_t n);         // Castagnoli, reflected, init/xorout 0xFFFFFFFF
uint32_t masked_crc32c(const uint8_t* data, size_t n);  // ((crc >> 15) | (crc << 17)) + 0xa282ead8
// The serialized Event protobuf of a SessionLog START (field 7, status 1).
std::string encode_session_start_event(double wall_time, int64_t step);
// The serialized Event protobuf (no TFRecord frame) of one step's scalars.
std::string encode_scalar_event(double wall_time, int64_t step,
                                const std::vector<std::pair<std::string, double>>& values);

}  // namespace flat::tensorboard
