#include "flat/train/best_validation.h"

#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"

namespace flat::train {

namespace fs = std::filesystem;

namespace {
nlohmann::json number(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); }
}  // namespace

BestValidation::BestValidation(std::string run_dir, double fall_db, int64_t warmup_steps)
    : run_dir_(std::move(run_dir)), fall_db_(fall_db), warmup_steps_(warmup_steps) {}

void BestValidation::resume() {
  const std::string file = run_dir_ + "/best/best.json";
  std::error_code ec;
  if (!fs::exists(file, ec)) return;
  try {
    std::ifstream in(file);
    const auto j = nlohmann::json::parse(in);
    best_psnr_ = j.at("val_psnr").get<double>();
    best_step_ = j.at("step").get<int64_t>();
    spdlog::info("resume: best held-out PSNR so far {:.2f} dB at step {} ({})", best_psnr_, best_step_, file);
  } catch (const std::exception& e) {
    fail(file + ": cannot read the best validation of this run: " + e.what() +
         " (remove the best/ folder to start keeping the best anew)");
  }
}

bool BestValidation::record(int64_t step, const ValidationResult& r, const std::string& weights_file_name,
                            const std::function<void(const std::string&)>& write_weights) {
  if (!std::isfinite(r.psnr)) return false;
  if (!std::isfinite(best_psnr_) || r.psnr > best_psnr_) {
    fs::create_directories(run_dir_ + "/best");
    // The weights first, then best.json naming them: a kill between the two
    // leaves the older best.json, which --resume reads as the best so far.
    write_weights(run_dir_ + "/best/" + weights_file_name);
    nlohmann::json j = {{"step", step},
                        {"val_psnr", r.psnr},
                        {"val_ssim", number(r.ssim)},
                        {"val_normal_cosine", number(r.normal_cosine)},
                        {"val_mean_colour_psnr", number(r.mean_colour_psnr)},
                        {"val_dataset_mean_psnr", number(r.dataset_mean_psnr)},
                        {"val_swap_psnr", number(r.swap_psnr)},
                        {"weights", weights_file_name}};
    write_file_atomic(run_dir_ + "/best/best.json", j.dump(2) + "\n");
    best_psnr_ = r.psnr;
    best_step_ = step;
    return true;
  }
  const double fall = best_psnr_ - r.psnr;
  if (fall_db_ > 0 && step > warmup_steps_ && fall > fall_db_) {
    ++falls_;
    spdlog::warn("held-out PSNR FELL: {:.2f} dB at step {}, {:.2f} dB below the best {:.2f} dB at step {} (mean-colour "
                 "oracle {:.2f} dB); the best model stays in {}/best (validation.fall_warning_db {})",
                 r.psnr, step, fall, best_psnr_, best_step_, r.mean_colour_psnr, run_dir_, fall_db_);
    fs::create_directories(run_dir_ + "/logs");
    const nlohmann::json line = {{"step", step},
                                 {"val_psnr", r.psnr},
                                 {"best_psnr", best_psnr_},
                                 {"best_step", best_step_},
                                 {"fall_db", fall},
                                 {"val_mean_colour_psnr", number(r.mean_colour_psnr)}};
    std::ofstream(run_dir_ + "/logs/val_falls.jsonl", std::ios::app) << line.dump() << "\n";
  }
  return false;
}

}  // namespace flat::train
