// flat_train's stop requests: SIGINT, SIGTERM and SIGHUP ask the training
// loop to stop after the current step and write a checkpoint (trainer.h);
// the loop reads the request with stop_signal_requested().
#pragma once
#include <cstdint>

namespace flat::train {

// Installs the stop handlers for its lifetime and restores the old ones after.
// A fresh StopSignals clears an earlier request.
class StopSignals {
 public:
  StopSignals();
  ~StopSignals();
  StopSignals(const StopSignals&) = delete;
  StopSignals& operator=(const StopSignals&) = delete;

 private:
  using Handler = void (*)(int);
  Handler old_int_, old_term_, old_hup_;
};

// The signal of the pending stop request; 0 when none came.
int stop_signal_requested();

// The test hook of kSignalInValidationEnv (trainer.h): raises its signal when
// `step` is the step it names.
void raise_test_signal_in_validation(int64_t step);

}  // namespace flat::train
