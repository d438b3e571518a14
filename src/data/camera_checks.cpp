#include "flat/data/camera_checks.h"

#include "flat/core/error.h"

namespace flat::data {

AxesFocus principal_axes_focus(const camera::Cameras& cameras) {
  cameras.check("principal_axes_focus");
  FLAT_CHECK(cameras.size() >= 2, "principal_axes_focus: needs at least 2 cameras");
  auto c2w = cameras.c2w.to(at::kDouble).cpu();
  auto o = c2w.narrow(1, 0, 3).select(2, 3);   // (V,3) centres
  auto d = c2w.narrow(1, 0, 3).select(2, 2);   // (V,3) optical axes (OpenCV +z)
  d = d / d.norm(2, 1, true);
  auto eye = at::eye(3, at::kDouble).unsqueeze(0);
  auto P = eye - d.unsqueeze(2) * d.unsqueeze(1);  // (V,3,3) projectors orthogonal to each axis
  auto A = P.sum(0), b = at::matmul(P, o.unsqueeze(2)).sum(0);
  FLAT_CHECK(std::abs(at::det(A).item<double>()) > 1e-12,
             "principal_axes_focus: optical axes are (nearly) parallel; no common point");
  auto p = at::linalg_solve(A, b).squeeze(1);
  auto off = at::matmul(P, (p - o).unsqueeze(2)).squeeze(2);  // (V,3) perpendicular offsets
  AxesFocus f;
  f.point = p;
  f.rms_distance = std::sqrt((off * off).sum(1).mean().item<double>());
  f.mean_camera_distance = (p - o).norm(2, 1).mean().item<double>();
  f.in_front = (((p - o) * d).sum(1) > 0).to(at::kDouble).mean().item<double>();
  return f;
}

}  // namespace flat::data
