// The learning-rate schedule: warm-up, then constant, cosine or linear decay.
#include <cmath>
#include <string>

#include "flat/train/lr_schedule.h"
#include "test_support.h"

using namespace flat::train;

namespace {
LrSchedule schedule(double peak, int64_t warmup, int64_t total, const std::string& shape, double min_ratio) {
  LrSchedule s;
  s.peak = peak;
  s.warmup_steps = warmup;
  s.total_steps = total;
  s.shape = shape;
  s.min_ratio = min_ratio;
  return s;
}
}  // namespace

TEST_CASE("learning-rate schedule: warm-up, then constant, cosine or linear decay", "[train]") {
  const LrSchedule s = schedule(1.0, 4, 14, "cosine", 0.1);
  CHECK(s.at(0) == Approx(0.25));
  CHECK(s.at(3) == Approx(1.0));
  CHECK(s.at(4) == Approx(1.0));    // first step after warm-up: the peak
  CHECK(s.at(13) == Approx(0.1));   // last step: min_ratio * peak
  CHECK(s.at(8) < s.at(5));
  CHECK(s.at(8) > 0.1);
  const double mid = 4 + 4.5;  // halfway through decay steps 4..13
  (void)mid;
  const LrSchedule lin = schedule(2.0, 0, 11, "linear", 0.0);
  CHECK(lin.at(0) == Approx(2.0));
  CHECK(lin.at(5) == Approx(1.0));
  CHECK(lin.at(10) == Approx(0.0).margin(1e-12));
  const LrSchedule c = schedule(3.0, 2, 10, "constant", 0.1);
  CHECK(c.at(0) == Approx(1.5));
  CHECK(c.at(9) == Approx(3.0));
  REQUIRE_THROWS(c.at(-1));
}
