// What a run records of itself: one JSON object per line in
// <run>/metrics/<stream>.jsonl ("train": every step; "val": every validation)
// and, when enabled, the same scalars under the same names as TensorBoard
// event files in <run>/tensorboard (scripts/check_tensorboard.py compares the
// two). Lines are flushed as they are written, so a killed run loses none.
#pragma once
#include <cstdint>
#include <fstream>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "flat/core/tensorboard_writer.h"

namespace flat::train {

using Scalars = std::vector<std::pair<std::string, double>>;

class MetricsLog {
 public:
  // resume_step >= 0: rows of an earlier session at or after that step (written
  // after its last checkpoint, then lost to a crash) are dropped first, so the
  // files read as one uninterrupted run.
  MetricsLog(const std::string& run_dir, bool tensorboard, int64_t resume_step = -1);
  void write(const std::string& stream, int64_t step, const Scalars& values);
  std::string file(const std::string& stream) const;

 private:
  std::string dir_;
  std::map<std::string, std::unique_ptr<std::ofstream>> files_;
  std::unique_ptr<tensorboard::TensorBoardWriter> tb_;
};

}  // namespace flat::train
