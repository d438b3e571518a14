#include "infer/stage_scores.h"

#include <algorithm>
#include <cmath>
#include <filesystem>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "flat/core/error.h"
#include "flat/eval/baselines.h"
#include "flat/eval/image_metrics.h"
#include "flat/eval/normal_metrics.h"
#include "flat/pipeline/scene_pipeline.h"

namespace fs = std::filesystem;

namespace flat::infer {

namespace {

Rendered render_all(const primitives::TriangleSoup& soup, const mesh::ViewTargets& t,
                    const render::RasterSettings& raster, int64_t chunk) {
  at::NoGradGuard no_grad;
  std::vector<at::Tensor> rgb, normal, alpha;
  for (int64_t s = 0; s < t.size(); s += chunk) {
    const auto views = at::arange(s, std::min(s + chunk, t.size()), at::kLong);
    const auto out = render::rasterize(soup.vertices, soup.colors, soup.opacities, soup.sigmas,
                                       t.cameras.index(views.to(t.cameras.c2w.device())), t.height(), t.width(),
                                       raster);
    const auto r = pipeline::normalise_by_alpha(out);
    rgb.push_back(r.rgb.cpu());
    normal.push_back(r.normal.cpu());
    alpha.push_back(r.alpha.cpu());
  }
  return {at::cat(rgb), at::cat(normal), at::cat(alpha)};
}

ViewScores score(const Rendered& r, const mesh::ViewTargets& t, const at::Tensor& views, loss::Lpips& lpips,
                 int64_t triangles, const Baselines& b) {
  ViewScores s;
  s.views = views.numel();
  s.triangles = triangles;
  if (s.views == 0) return s;
  const auto rgb = r.rgb.index_select(0, views).clamp(0, 1);
  const auto gt = t.rgb.cpu().index_select(0, views);
  s.psnr = eval::psnr(rgb, gt).mean().item<double>();
  s.ssim = eval::ssim(rgb, gt).mean().item<double>();
  if (!lpips.is_empty()) s.lpips = eval::lpips(lpips, rgb, gt).mean().item<double>();
  s.mean_colour_psnr = eval::mean_colour_psnr(gt).mean().item<double>();
  if (b.swap.defined()) {
    s.dataset_mean_psnr = eval::psnr(b.dataset_mean.index_select(0, views), gt).mean().item<double>();
    s.swap_psnr = eval::psnr(rgb, b.swap.index_select(0, views)).mean().item<double>();
  }
  if (t.normals.defined()) {
    const auto acc = eval::normal_accuracy(r.normal.index_select(0, views), t.normals.cpu().index_select(0, views),
                                           r.alpha.index_select(0, views) > 0.5);
    s.normal_cosine = acc.mean_cosine;
  }
  return s;
}

}  // namespace

Baselines load_baselines(const std::vector<std::string>& scene_dirs, const data::Scene& scene,
                         const MeshSource& source, const mesh::ViewTargets& views) {
  Baselines baselines;
  std::vector<at::Tensor> others;
  for (const auto& dir : scene_dirs) {
    auto other = data::read_scene(dir);
    data::choose_latent_set(other, source.latent_set);
    if (fs::equivalent(other.dir, scene.dir)) continue;
    auto t = load_window_targets(other, source.window, false, false);
    FLAT_CHECK(t.size() == views.size() && t.height() == views.height() && t.width() == views.width(),
               fmt::format("--baseline-scenes {}: window {} has {} frames of {}x{}, this scene {} of {}x{}", dir,
                           source.window, t.size(), t.height(), t.width(), views.size(), views.height(),
                           views.width()));
    others.push_back(t.rgb.cpu());
  }
  if (!others.empty()) {
    baselines.swap = others.front();
    baselines.dataset_mean = at::stack(others).mean(0);
    spdlog::info("baselines: {} other scenes (dataset mean); swap against {}", others.size(), scene_dirs.front());
  }
  return baselines;
}

nlohmann::json to_json(const ViewScores& s) {
  const auto num = [](double x) { return std::isfinite(x) ? nlohmann::json(x) : nlohmann::json(nullptr); };
  return {{"views", s.views},         {"triangles", s.triangles}, {"psnr", num(s.psnr)},
          {"ssim", num(s.ssim)},      {"lpips", num(s.lpips)},    {"normal_cosine", num(s.normal_cosine)},
          {"mean_colour_psnr", num(s.mean_colour_psnr)}, {"dataset_mean_psnr", num(s.dataset_mean_psnr)},
          {"swap_psnr", num(s.swap_psnr)}};
}

StageScorer::StageScorer(const mesh::ViewTargets& views, const ViewSplit& split, loss::Lpips lpips,
                         Baselines baselines, int64_t chunk)
    : views_(views), split_(split), lpips_(std::move(lpips)), baselines_(std::move(baselines)), chunk_(chunk) {}

void StageScorer::add(const std::string& name, const primitives::TriangleSoup& soup,
                      const render::RasterSettings& raster, MeshRunSummary& summary) {
  stages_.push_back(render_all(soup, views_, raster, chunk_));
  const int64_t n = soup.vertices.size(0);
  auto& scores = summary.scores[name];
  scores["fitted"] = score(stages_.back(), views_, split_.fitted, lpips_, n, baselines_);
  scores["held_out"] = score(stages_.back(), views_, split_.held_out, lpips_, n, baselines_);
  const auto& f = scores["fitted"];
  const auto& h = scores["held_out"];
  spdlog::info("{}: {} triangles; fitted views PSNR {:.2f} dB (mean-colour oracle {:.2f}), normal cosine {:.3f}; "
               "held-out views PSNR {:.2f} dB (oracle {:.2f}, dataset mean {:.2f}, swap {:.2f}), normal cosine {:.3f}",
               name, n, f.psnr, f.mean_colour_psnr, f.normal_cosine, h.psnr, h.mean_colour_psnr, h.dataset_mean_psnr,
               h.swap_psnr, h.normal_cosine);
}

}  // namespace flat::infer
