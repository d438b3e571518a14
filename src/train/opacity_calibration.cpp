#include "flat/train/opacity_calibration.h"

#include <cmath>
#include <limits>

#include <fmt/format.h>
#include <torch/torch.h>

#include "flat/core/autocast_scope.h"
#include "flat/core/error.h"
#include "flat/train/data_parallel.h"
#include "flat/train/train_step.h"

namespace flat::train {

std::vector<double> opacity_shift_candidates(double current) {
  std::vector<double> shifts;
  for (int k = 0; k <= 12; ++k) shifts.push_back(current - 0.5 * k);
  return shifts;
}

at::Tensor reshift_opacities(const at::Tensor& opacities, double from, double to) {
  const double eps = 1e-6;
  return at::sigmoid(at::logit(opacities, eps) + (from - to));
}

std::string OpacityShiftCalibration::table() const {
  std::string out;
  for (const auto& t : trials)
    out += fmt::format("\n  opacity_shift {:5.2f}: rgb {:.5f}, {:5.1f}% kept{}", t.shift, t.rgb, 100 * t.kept,
                       t.shift == best ? "  <- chosen" : "");
  return out;
}

namespace {

// The scene with its opacities replaced (the other tensors shared).
primitives::ScenePrimitives with_opacities(const primitives::ScenePrimitives& scene, const at::Tensor& opacities) {
  std::vector<at::Tensor> tensors;
  for (const auto& [name, t] : scene.named_tensors()) tensors.push_back(name == "opacities" ? opacities : t);
  return scene.with_tensors(tensors);
}

}  // namespace

OpacityShiftCalibration calibrate_opacity_shift(pipeline::ScenePipeline& pipeline, loss::Objective& objective,
                                                data::Loader& loader, int64_t batches, double prune_opacity,
                                                bool bf16, int64_t background_seed, DataParallel* dp) {
  FLAT_CHECK(batches > 0, "opacity calibration: needs at least one batch");
  FLAT_CHECK(prune_opacity > 0, "opacity calibration: only a stage that prunes (pipeline.prune_opacity > 0) needs it");
  at::NoGradGuard no_grad;
  const double current = pipeline.config().triangles.opacity_shift;
  OpacityShiftCalibration c;
  for (double s : opacity_shift_candidates(current)) c.trials.push_back({s, 0.0, 0.0});
  const auto device = pipeline.decoder()->conv2->weight.device();
  for (int64_t k = 0; k < batches; ++k) {
    const data::Batch batch = loader.batch(k);  // training batch k, the stream left as it is
    FLAT_CHECK(batch.video_latents.defined(), "opacity calibration: the batch has no latents (data.latents: true)");
    primitives::ScenePrimitives scene;
    {
      AutocastScope autocast(bf16 && device.is_cuda(), device.type());
      scene = pipeline.decode({batch.video_latents, batch.camera_latents, batch.input_intrinsics, batch.input_c2w});
    }
    const at::Tensor opacities = scene.opacities().to(at::kFloat);
    const int64_t seed = background_seed < 0 ? -1 : background_seed * 1000003 + 999983 * (k + 1);
    for (auto& t : c.trials) {
      const at::Tensor o = reshift_opacities(opacities, current, t.shift);
      const StepResult r = score_decoded(pipeline, objective, batch, with_opacities(scene, o), seed, prune_opacity);
      FLAT_CHECK(r.finite, fmt::format("opacity calibration: the loss at opacity_shift {} is not finite ({})", t.shift,
                                       r.nonfinite));
      // The rgb term (what pruning takes away); the total when the objective has none.
      const auto rgb = r.terms.find("rgb");
      t.rgb += (rgb != r.terms.end() ? rgb->second : r.loss) / double(batches);
      t.kept += (o >= prune_opacity).to(at::kFloat).mean().item<double>() / double(batches);
    }
  }
  if (dp) {  // the mean over the ranks: every rank chooses the same shift
    std::vector<double> values;
    for (const auto& t : c.trials) values.insert(values.end(), {t.rgb, t.kept});
    values = dp->sum(values);
    for (size_t i = 0; i < c.trials.size(); ++i) {
      c.trials[i].rgb = values[2 * i] / double(dp->world_size());
      c.trials[i].kept = values[2 * i + 1] / double(dp->world_size());
    }
  }
  double best_rgb = std::numeric_limits<double>::infinity();
  for (const auto& t : c.trials)
    if (t.rgb < best_rgb) best_rgb = t.rgb, c.best = t.shift;
  return c;
}

}  // namespace flat::train
