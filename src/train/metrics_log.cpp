#include "flat/train/metrics_log.h"

#include <cmath>
#include <filesystem>
#include <sstream>

#include <nlohmann/json.hpp>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"

namespace flat::train {
namespace fs = std::filesystem;

namespace {

// Keeps the lines whose "step" is below `step`.
void drop_rows_from(const std::string& path, int64_t step) {
  std::ifstream in(path);
  if (!in) return;
  std::string kept, line;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    try {
      if (nlohmann::json::parse(line).at("step").get<int64_t>() >= step) continue;
    } catch (const nlohmann::json::exception&) {
      continue;  // a line cut short by a crash
    }
    kept += line + "\n";
  }
  write_file_atomic(path, kept);
}

}  // namespace

MetricsLog::MetricsLog(const std::string& run_dir, bool tensorboard, int64_t resume_step)
    : dir_(run_dir + "/metrics") {
  std::error_code ec;
  fs::create_directories(dir_, ec);
  if (ec) fail(dir_ + ": cannot create (" + ec.message() + ")");
  if (resume_step >= 0)
    for (const auto& e : fs::directory_iterator(dir_, ec))
      if (e.path().extension() == ".jsonl") drop_rows_from(e.path().string(), resume_step);
  if (tensorboard) {
    tb_ = std::make_unique<tensorboard::TensorBoardWriter>(run_dir + "/tensorboard");
    if (resume_step >= 0) {
      tb_->add_session_start(resume_step);  // TensorBoard drops the lost steps of the earlier session
      tb_->flush();
    }
  }
}

std::string MetricsLog::file(const std::string& stream) const { return dir_ + "/" + stream + ".jsonl"; }

void MetricsLog::write(const std::string& stream, int64_t step, const Scalars& values) {
  auto& f = files_[stream];
  if (!f) {
    f = std::make_unique<std::ofstream>(file(stream), std::ios::app);
    if (!*f) fail(file(stream) + ": cannot open for appending");
  }
  nlohmann::json row = {{"step", step}};
  for (const auto& [k, v] : values) {
    if (std::isfinite(v)) row[k] = v;
    else row[k] = nullptr;  // JSON has no NaN; the TensorBoard file keeps it
  }
  *f << row.dump() << "\n";
  f->flush();
  if (!*f) fail(file(stream) + ": write failed");
  if (tb_) {
    tb_->add_scalars(values, step);
    tb_->flush();
  }
}

}  // namespace flat::train
