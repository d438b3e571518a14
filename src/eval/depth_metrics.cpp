#include "flat/eval/depth_metrics.h"

#include <string>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::eval {

namespace {

// x's interior (every pixel but the 1-pixel border).
at::Tensor interior(const at::Tensor& x) { return x.slice(2, 1, x.size(2) - 1).slice(3, 1, x.size(3) - 1); }

// The 8 neighbours of every interior pixel, each as a tensor the interior's size.
std::vector<at::Tensor> neighbours(const at::Tensor& x) {
  const int64_t H = x.size(2), W = x.size(3);
  std::vector<at::Tensor> out;
  for (int64_t dy = -1; dy <= 1; ++dy)
    for (int64_t dx = -1; dx <= 1; ++dx)
      if (dy != 0 || dx != 0) out.push_back(x.slice(2, 1 + dy, H - 1 + dy).slice(3, 1 + dx, W - 1 + dx));
  return out;
}

bool has_interior(const at::Tensor& x) { return x.size(2) >= 3 && x.size(3) >= 3; }

void check_depth(const at::Tensor& t, const std::string& what) { check_shape(t, {-1, 1, -1, -1}, what, "(V,1,H,W)"); }

void check_same(const at::Tensor& t, const at::Tensor& like, const std::string& what) {
  FLAT_CHECK(t.size(0) == like.size(0) && t.size(2) == like.size(2) && t.size(3) == like.size(3),
             what + " " + shape_str(t) + " does not match the rendered depth " + shape_str(like));
}

// rho on an undefined-free float64 depth; NaN where undefined (see the header).
at::Tensor rho_of(const at::Tensor& z) {
  auto out = at::full_like(z, NAN);
  if (!has_interior(z)) return out;
  auto has = z > 0;
  auto inv = at::where(has, 1.0 / z, at::zeros_like(z));
  auto all = interior(has).clone();
  auto sum = at::zeros_like(interior(z));
  for (const auto& n : neighbours(inv)) sum = sum + n;
  for (const auto& n : neighbours(has)) all = all & n;
  auto rho = (sum / 8.0) * interior(z) - 1.0;
  interior(out).copy_(at::where(all, rho, at::full_like(rho, NAN)));
  return out;
}

at::Tensor planar_from(const at::Tensor& rho_ref, const at::Tensor& reference_normals) {
  auto planar = at::isfinite(rho_ref) & (rho_ref.abs() < kPlanarDepthTolerance);
  if (!reference_normals.defined() || !has_interior(rho_ref)) return planar;
  auto n = reference_normals.detach().to(at::kCPU, at::kDouble);
  auto len = n.norm(2, 1, true);
  auto has = len > 0.5;
  n = n / len.clamp_min(1e-12);
  auto centre = interior(n);
  auto same = interior(has).clone();
  const auto nn = neighbours(n), nh = neighbours(has);
  for (size_t k = 0; k < nn.size(); ++k) same = same & nh[k] & ((nn[k] * centre).sum(1, true) >= kPlanarNormalCosine);
  auto in = interior(planar);
  in.copy_(in & same);  // the border stays false (rho is NaN there)
  return planar;
}

}  // namespace

at::Tensor relative_disparity_laplacian(const at::Tensor& depth) {
  check_depth(depth, "relative_disparity_laplacian: depth");
  return rho_of(depth.detach().to(at::kCPU, at::kDouble));
}

at::Tensor planar_mask(const at::Tensor& reference, const at::Tensor& reference_normals) {
  check_depth(reference, "planar_mask: reference depth");
  if (reference_normals.defined()) {
    check_shape(reference_normals, {-1, 3, -1, -1}, "planar_mask: reference normals", "(V,3,H,W)");
    check_same(reference_normals, reference, "planar_mask: reference normals");
  }
  return planar_from(relative_disparity_laplacian(reference), reference_normals);
}

at::Tensor si_log_error(const at::Tensor& rendered, const at::Tensor& reference, const at::Tensor& mask) {
  check_depth(rendered, "si_log_error: rendered depth");
  check_depth(reference, "si_log_error: reference depth");
  check_same(reference, rendered, "si_log_error: reference depth");
  auto r = rendered.detach().to(at::kCPU, at::kDouble), R = reference.detach().to(at::kCPU, at::kDouble);
  auto valid = (r > 0) & (R > 0) & at::isfinite(r) & at::isfinite(R);
  if (mask.defined()) {
    check_depth(mask, "si_log_error: mask");
    check_same(mask, rendered, "si_log_error: mask");
    valid = valid & mask.to(at::kCPU).to(at::kBool);
  }
  auto m = valid.to(at::kDouble);
  auto d = at::where(valid, r.clamp_min(1e-30).log() - R.clamp_min(1e-30).log(), at::zeros_like(r));
  auto count = m.sum({1, 2, 3});
  auto mean = d.sum({1, 2, 3}) / count.clamp_min(1);
  // The standard deviation of d: Eigen's sqrt(mean(d^2) - mean(d)^2) without its cancellation.
  auto var = ((d - mean.view({-1, 1, 1, 1})).square() * m).sum({1, 2, 3}) / count.clamp_min(1);
  return at::where(count > 0, var.sqrt(), at::full_like(var, NAN));
}

DepthAccuracy depth_accuracy(const at::Tensor& rendered, const at::Tensor& reference, const at::Tensor& mask,
                             const at::Tensor& reference_normals) {
  check_depth(rendered, "depth_accuracy: rendered depth");
  check_depth(reference, "depth_accuracy: reference depth");
  check_same(reference, rendered, "depth_accuracy: reference depth");
  if (reference_normals.defined()) {
    check_shape(reference_normals, {-1, 3, -1, -1}, "depth_accuracy: reference normals", "(V,3,H,W)");
    check_same(reference_normals, rendered, "depth_accuracy: reference normals");
  }
  auto r = rendered.detach().to(at::kCPU, at::kDouble), R = reference.detach().to(at::kCPU, at::kDouble);
  auto covered = (r > 0) & at::isfinite(r);
  if (mask.defined()) {
    check_depth(mask, "depth_accuracy: mask");
    check_same(mask, rendered, "depth_accuracy: mask");
    covered = covered & mask.to(at::kCPU).to(at::kBool);
  }
  DepthAccuracy out;
  auto si = si_log_error(r, R, covered);
  for (int64_t v = 0; v < si.size(0); ++v) out.si_log.push_back(si[v].item<double>());
  out.depth_pixels = (covered & (R > 0)).sum().item<int64_t>();
  // Uncovered pixels get no depth, so rho(rendered) is NaN wherever the 3x3 is not all rendered.
  auto rho_r = rho_of(at::where(covered, r, at::zeros_like(r)));
  auto rho_R = rho_of(R);
  auto scored = planar_from(rho_R, reference_normals) & at::isfinite(rho_r);
  out.planar_pixels = scored.sum().item<int64_t>();
  if (out.planar_pixels > 0)
    out.planar_roughness_sum = at::where(scored, (rho_r - rho_R).abs(), at::zeros_like(rho_r)).sum().item<double>();
  return out;
}

}  // namespace flat::eval
