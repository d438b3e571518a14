#include "flat/eval/normal_metrics.h"

#include <cmath>
#include <limits>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::eval {

NormalAccuracy normal_accuracy(const at::Tensor& rendered, const at::Tensor& reference, const at::Tensor& mask) {
  check_shape(rendered, {-1, 3, -1, -1}, "normal_accuracy: rendered normals", "(V,3,H,W)");
  FLAT_CHECK(reference.sizes() == rendered.sizes(), "normal_accuracy: reference normals " +
                                                        shape_str(reference) + " do not match rendered " +
                                                        shape_str(rendered));
  auto n = rendered.detach().to(at::kDouble), N = reference.detach().to(at::kDouble);
  auto ln = n.norm(2, 1, true), lN = N.norm(2, 1, true);
  auto valid = (ln > 1e-6) & (lN > 1e-6);
  if (mask.defined()) {
    check_shape(mask, {rendered.size(0), 1, rendered.size(2), rendered.size(3)}, "normal_accuracy: mask",
                "(V,1,H,W)");
    valid = valid & mask.to(at::kBool);
  }
  n = n / ln.clamp_min(1e-12);
  N = N / lN.clamp_min(1e-12);
  NormalAccuracy out;
  auto m = valid.to(at::kDouble);
  out.valid_pixels = valid.sum().item<int64_t>();
  if (out.valid_pixels == 0) {
    out.mean_cosine = out.mean_l1 = std::numeric_limits<double>::quiet_NaN();
    return out;
  }
  out.mean_cosine = ((n * N).sum(1, true) * m).sum().item<double>() / double(out.valid_pixels);
  out.mean_l1 = ((n - N).abs() * m).sum().item<double>() / (3.0 * double(out.valid_pixels));
  return out;
}

}  // namespace flat::eval
