// The best held-out validation of a run, kept beside the last (issue #44: a
// stage whose held-out figure falls must not cost the user the good model):
//   <run>/best/model.safetensors (scene task) or best/vae.safetensors (VAE
//   task), the weights of the validation with the highest held-out PSNR so
//   far, written atomically when a validation beats it;
//   <run>/best/best.json: its step, PSNR and baselines (read back by --resume);
//   <run>/logs/val_falls.jsonl: one line per validation after the warm-up
//   that falls more than validation.fall_warning_db below the best before it,
//   with the numbers; the same as a warning in the log.
#pragma once
#include <cmath>
#include <cstdint>
#include <functional>
#include <string>

#include "flat/train/validation.h"

namespace flat::train {

class BestValidation {
 public:
  // run_dir: the run folder; fall_db: the fall that is warned about (0 = never);
  // warmup_steps: validations up to this step are never called falls.
  BestValidation(std::string run_dir, double fall_db, int64_t warmup_steps);
  // Restores the best so far from best/best.json (a resumed run); no file: none yet.
  void resume();
  // Called on rank 0 after each validation. write_weights(path) writes the
  // model to `path`; it is called only for a new best. Returns true for a new best.
  bool record(int64_t step, const ValidationResult& result, const std::string& weights_file_name,
              const std::function<void(const std::string&)>& write_weights);
  double best_psnr() const { return best_psnr_; }
  int64_t best_step() const { return best_step_; }
  int64_t falls() const { return falls_; }

 private:
  std::string run_dir_;
  double fall_db_;
  int64_t warmup_steps_;
  double best_psnr_ = NAN;
  int64_t best_step_ = -1;
  int64_t falls_ = 0;
};

}  // namespace flat::train
