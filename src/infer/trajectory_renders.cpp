#include "flat/infer/trajectory_renders.h"

#include <algorithm>
#include <chrono>

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/progress.h"
#include "flat/core/tensor_io.h"
#include "flat/data/scene.h"

namespace flat::infer {

std::pair<double, double> display_depth_range(const primitives::ScenePrimitives& scene,
                                              const camera::Cameras& cameras) {
  if (!scene.opacities().defined() || scene.size() == 0) return {0.1, 10.0};
  auto centroids = scene.centres().detach().to(at::kCPU, at::kFloat);  // (N,3)
  // Percentiles of an evenly spaced sample are enough for display, and keep
  // many cameras of millions of triangles cheap.
  const int64_t n = centroids.size(0), stride = std::max<int64_t>(1, n / 100000);
  centroids = centroids.slice(0, 0, n, stride);
  auto w2c = camera::world_to_camera(cameras.c2w.to(at::kCPU, at::kFloat));  // (V,4,4)
  // Every camera's own percentiles, then the widest: a dolly's closest frames
  // keep their depth contrast instead of saturating at the near end.
  double lo = 0, hi = 0;
  bool any = false;
  for (int64_t v = 0; v < w2c.size(0); ++v) {
    auto z = centroids.matmul(w2c[v].slice(0, 2, 3).slice(1, 0, 3).t()).squeeze(1) + w2c[v][2][3];
    z = z.masked_select(z > 1e-3);
    if (z.numel() < 2) continue;
    auto q = at::quantile(z, at::tensor({0.02f, 0.98f}));
    const double a = q[0].item<double>(), b = q[1].item<double>();
    lo = any ? std::min(lo, a) : a;
    hi = any ? std::max(hi, b) : b;
    any = true;
  }
  if (!any) return {0.1, 10.0};
  return hi > lo ? std::make_pair(lo, hi) : std::make_pair(lo, lo + 1.0);
}

namespace {

at::Tensor depth_grey(const at::Tensor& depth, double lo, double hi) {  // (K,1,H,W) -> (K,3,H,W)
  auto d = ((hi - depth) / (hi - lo)).clamp(0.05, 1.0);
  d = at::where(depth > 0, d, at::zeros_like(d));
  return d.expand({-1, 3, -1, -1});
}

}  // namespace

TrajectoryRenders render_trajectory(pipeline::ScenePipeline& pipeline, const primitives::ScenePrimitives& scene,
                                    const camera::Cameras& cams, int64_t height, int64_t width,
                                    const std::string& folder, int64_t chunk, bool keep_video_frames,
                                    std::pair<double, double> depth_range, const std::string& progress_label) {
  FLAT_CHECK(chunk > 0, "render: chunk must be positive");
  torch::NoGradGuard no_grad;
  const auto t0 = std::chrono::steady_clock::now();
  const auto device = scene.opacities().device();
  TrajectoryRenders out;
  out.depth_range = depth_range;
  out.views = cams.size();
  std::vector<at::Tensor> frames;
  double alpha_sum = 0, uncovered = 0;
  Progress progress(progress_label, out.views);
  for (int64_t v0 = 0; v0 < out.views; v0 += chunk) {
    const int64_t v1 = std::min(out.views, v0 + chunk);
    camera::Cameras part{cams.intrinsics.slice(0, v0, v1).to(device), cams.c2w.slice(0, v0, v1).to(device)};
    auto r = pipeline.render(scene, part, height, width);
    auto rgb = r.rgb.to(at::kCPU, at::kFloat).clamp(0, 1);
    auto alpha = r.alpha.to(at::kCPU, at::kFloat);
    auto depth = r.depth.to(at::kCPU, at::kFloat);
    auto normal = r.normal.to(at::kCPU, at::kFloat);
    alpha_sum += alpha.sum().item<double>();
    uncovered += (alpha < 0.5).sum().item<double>();
    auto grey = depth_grey(depth, depth_range.first, depth_range.second);
    auto nvis = at::where(normal.norm(2, 1, true) > 0.5, (normal * 0.5 + 0.5).clamp(0, 1), at::zeros_like(normal));
    for (int64_t k = 0; k < v1 - v0 && !folder.empty(); ++k) {
      const std::string stem = data::frame_stem(v0 + k);
      if (image_io_available()) {
        write_image(folder + "/rgb/" + stem + ".png", rgb[k]);
        write_image(folder + "/depth/" + stem + ".png", grey[k], /*png16=*/true);
        write_image(folder + "/normal/" + stem + ".png", nvis[k]);
        write_image(folder + "/alpha/" + stem + ".png", alpha[k]);
      } else {
        save_safetensors(folder + "/" + stem + ".safetensors",
                         {{"rgb", rgb[k]}, {"alpha", alpha[k]}, {"depth", depth[k]}, {"normal", normal[k]}},
                         {{"layout", "(C,H,W) float32; depth metric, alpha-normalised; normal camera space"}});
      }
    }
    if (keep_video_frames)
      frames.push_back(at::cat({rgb, grey, nvis}, 3).mul(255).round().to(at::kByte));
    progress.step(v1 - v0);
  }
  progress.finish();
  out.mean_alpha = alpha_sum / double(std::max<int64_t>(1, out.views * height * width));
  out.uncovered = uncovered / double(std::max<int64_t>(1, out.views * height * width));
  if (keep_video_frames && !frames.empty()) out.video_frames = at::cat(frames, 0);
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

}  // namespace flat::infer
