#include "flat/eval/evaluation_report.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "flat/core/error.h"
#include "flat/eval/depth_metrics.h"
#include "eval/mean_of.h"

namespace flat::eval {

namespace {

void accumulate(Means& m, const std::vector<const SceneScore*>& scores) {
  std::vector<double> psnr, ssim, lpips, l1, cosine, si_log, roughness, oracle, dataset_mean, swap;
  for (const auto* s : scores) {
    if (!s->ok) {
      ++m.failed;
      continue;
    }
    ++m.scenes;
    if (s->latent_encoder == "random") ++m.random_latent_scenes;
    if (std::isfinite(s->mean_colour_psnr)) oracle.push_back(s->mean_colour_psnr);
    if (std::isfinite(s->dataset_mean_psnr)) dataset_mean.push_back(s->dataset_mean_psnr);
    if (std::isfinite(s->swap_psnr)) swap.push_back(s->swap_psnr);
    psnr.push_back(s->psnr);
    ssim.push_back(s->ssim);
    if (std::isfinite(s->lpips)) lpips.push_back(s->lpips);
    if (s->normal_pixels > 0) {
      l1.push_back(s->normal_l1);
      cosine.push_back(s->normal_cosine);
    }
    if (std::isfinite(s->depth_si_log)) si_log.push_back(s->depth_si_log);
    if (std::isfinite(s->planar_roughness)) roughness.push_back(s->planar_roughness);
  }
  m.psnr = mean_of(psnr);
  m.ssim = mean_of(ssim);
  m.lpips = mean_of(lpips);
  m.normal_l1 = mean_of(l1);
  m.normal_cosine = mean_of(cosine);
  m.normal_scenes = int64_t(l1.size());
  m.depth_si_log = mean_of(si_log);
  m.planar_roughness = mean_of(roughness);
  m.depth_scenes = int64_t(si_log.size());
  m.mean_colour_psnr = mean_of(oracle);
  m.dataset_mean_psnr = mean_of(dataset_mean);
  m.swap_psnr = mean_of(swap);
}

nlohmann::json number(double x) { return std::isfinite(x) ? nlohmann::json(x) : nlohmann::json(nullptr); }
double number(const nlohmann::json& j) { return j.is_number() ? j.get<double>() : NAN; }

std::string cell(double x, int decimals) { return std::isfinite(x) ? fmt::format("{:.{}f}", x, decimals) : "–"; }

std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\n") == std::string::npos) return s;
  std::string q = "\"";
  for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c);
  return q + "\"";
}

}  // namespace

std::vector<Means> dataset_means(const std::vector<SceneScore>& scores) {
  std::vector<std::string> order;
  std::map<std::string, std::vector<const SceneScore*>> by;
  std::vector<const SceneScore*> all;
  for (const auto& s : scores) {
    if (!by.count(s.dataset)) order.push_back(s.dataset);
    by[s.dataset].push_back(&s);
    all.push_back(&s);
  }
  std::vector<Means> out;
  for (const auto& d : order) {
    Means m;
    m.dataset = d;
    accumulate(m, by[d]);
    out.push_back(m);
  }
  Means overall;
  accumulate(overall, all);
  out.push_back(overall);
  return out;
}

std::string results_csv(const EvalResults& r) {
  std::ostringstream os;
  os << "dataset,scene,status,views,unseen_views,triangles,psnr,ssim,lpips,normal_l1,normal_cosine,normal_pixels,"
        "depth_si_log,planar_roughness,planar_pixels,mean_colour_psnr,dataset_mean_psnr,swap_psnr,swap_scene,latent_encoder,seconds,error\n";
  for (const auto& s : r.scores) {
    auto num = [](double x) { return std::isfinite(x) ? fmt::format("{:.6g}", x) : std::string(); };
    os << csv_field(s.dataset) << ',' << csv_field(s.scene) << ',' << (s.ok ? "ok" : "failed") << ',' << s.views
       << ',' << s.unseen_views << ',' << s.triangles << ',' << num(s.psnr) << ',' << num(s.ssim) << ','
       << num(s.lpips) << ',' << num(s.normal_l1) << ',' << num(s.normal_cosine) << ',' << s.normal_pixels << ','
       << num(s.depth_si_log) << ',' << num(s.planar_roughness) << ',' << s.planar_pixels << ','
       << num(s.mean_colour_psnr) << ',' << num(s.dataset_mean_psnr) << ',' << num(s.swap_psnr) << ','
       << csv_field(s.swap_scene) << ',' << csv_field(s.latent_encoder) << ',' << fmt::format("{:.3f}", s.seconds) << ',' << csv_field(s.error) << '\n';
  }
  return os.str();
}

nlohmann::json score_to_json(const SceneScore& s) {
  return {{"dataset", s.dataset}, {"scene", s.scene}, {"dir", s.dir}, {"ok", s.ok}, {"error", s.error},
          {"views", s.views}, {"unseen_views", s.unseen_views}, {"triangles", s.triangles},
          {"psnr", number(s.psnr)}, {"ssim", number(s.ssim)}, {"lpips", number(s.lpips)},
          {"normal_l1", number(s.normal_l1)}, {"normal_cosine", number(s.normal_cosine)},
          {"normal_pixels", s.normal_pixels}, {"depth_si_log", number(s.depth_si_log)},
          {"planar_roughness", number(s.planar_roughness)}, {"planar_pixels", s.planar_pixels},
          {"mean_colour_psnr", number(s.mean_colour_psnr)},
          {"dataset_mean_psnr", number(s.dataset_mean_psnr)}, {"swap_psnr", number(s.swap_psnr)},
          {"swap_scene", s.swap_scene}, {"latent_encoder", s.latent_encoder}, {"seconds", s.seconds}};
}

SceneScore score_from_json(const nlohmann::json& s) {
  SceneScore x;
  x.dataset = s.at("dataset").get<std::string>();
  x.scene = s.at("scene").get<std::string>();
  x.dir = s.value("dir", "");
  x.ok = s.at("ok").get<bool>();
  x.error = s.value("error", "");
  x.views = s.at("views").get<int64_t>();
  x.unseen_views = s.value("unseen_views", int64_t(0));
  x.triangles = s.value("triangles", int64_t(0));
  x.psnr = number(s.at("psnr"));
  x.ssim = number(s.at("ssim"));
  x.lpips = number(s.at("lpips"));
  x.normal_l1 = number(s.at("normal_l1"));
  x.normal_cosine = number(s.at("normal_cosine"));
  x.normal_pixels = s.value("normal_pixels", int64_t(0));
  // Results written before the depth measures have none (NaN).
  x.depth_si_log = s.contains("depth_si_log") ? number(s.at("depth_si_log")) : NAN;
  x.planar_roughness = s.contains("planar_roughness") ? number(s.at("planar_roughness")) : NAN;
  x.planar_pixels = s.value("planar_pixels", int64_t(0));
  x.mean_colour_psnr = s.contains("mean_colour_psnr") ? number(s.at("mean_colour_psnr")) : NAN;
  x.dataset_mean_psnr = s.contains("dataset_mean_psnr") ? number(s.at("dataset_mean_psnr")) : NAN;
  x.swap_psnr = s.contains("swap_psnr") ? number(s.at("swap_psnr")) : NAN;
  x.swap_scene = s.value("swap_scene", "");
  x.latent_encoder = s.value("latent_encoder", "");
  x.seconds = s.value("seconds", 0.0);
  return x;
}

nlohmann::json results_json(const EvalResults& r) {
  nlohmann::json scenes = nlohmann::json::array();
  for (const auto& s : r.scores) scenes.push_back(score_to_json(s));
  nlohmann::json means = nlohmann::json::array();
  for (const auto& m : dataset_means(r.scores)) {
    means.push_back({{"dataset", m.dataset.empty() ? nlohmann::json(nullptr) : nlohmann::json(m.dataset)},
                     {"scenes", m.scenes}, {"failed", m.failed}, {"normal_scenes", m.normal_scenes},
                     {"psnr", number(m.psnr)}, {"ssim", number(m.ssim)}, {"lpips", number(m.lpips)},
                     {"normal_l1", number(m.normal_l1)}, {"normal_cosine", number(m.normal_cosine)},
                     {"depth_scenes", m.depth_scenes}, {"depth_si_log", number(m.depth_si_log)},
                     {"planar_roughness", number(m.planar_roughness)},
                     {"mean_colour_psnr", number(m.mean_colour_psnr)},
                     {"dataset_mean_psnr", number(m.dataset_mean_psnr)}, {"swap_psnr", number(m.swap_psnr)},
                     {"random_latent_scenes", m.random_latent_scenes}});
  }
  const auto overall = dataset_means(r.scores).back();
  return {{"format", "flat-eval-1"}, {"name", r.name},     {"model", r.model}, {"settings", r.settings},
          {"ssim", r.ssim},          {"prune_opacity", number(r.prune_opacity)}, {"scenes", scenes},
          {"means", means},
          {"latent_encoder", overall.random_latent_scenes > 0 ? "random" : "pretrained"},
          {"random_latent_scenes", overall.random_latent_scenes},
          {"definitions", metric_definitions(r.ssim)}};
}

EvalResults read_results_json(const std::string& path) {
  std::ifstream in(path);
  if (!in) fail(path + ": cannot open (expected a flat_eval output folder's results.json)");
  EvalResults r;
  try {
    auto j = nlohmann::json::parse(in);
    FLAT_CHECK(j.value("format", "") == "flat-eval-1", path + ": not a flat_eval results file");
    r.name = j.at("name").get<std::string>();
    r.model = j.at("model").get<std::string>();
    r.settings = j.at("settings").get<std::string>();
    r.ssim = j.at("ssim").get<std::string>();
    if (j.contains("prune_opacity") && j["prune_opacity"].is_number()) r.prune_opacity = j["prune_opacity"].get<double>();
    for (const auto& s : j.at("scenes")) r.scores.push_back(score_from_json(s));
  } catch (const nlohmann::json::exception& e) {
    fail(path + ": malformed results file (" + e.what() + ")");
  }
  return r;
}

std::string metric_definitions(const std::string& ssim_convention) {
  std::string ssim = ssim_convention == "3dgs"
                         ? "SSIM: the 3DGS repositories' ssim(): Gaussian 11x11, sigma 1.5, zero padding of 5 "
                           "pixels, mean over every pixel (not scikit-image's values)."
                         : "SSIM: scikit-image structural_similarity with Wang et al.'s settings: Gaussian 11x11, "
                           "sigma 1.5, population covariance, statistics where the window fits (valid), mean.";
  return "PSNR: 10 log10(1/MSE) per view over RGB in [0,1], mean over a scene's views, then over scenes.\n" + ssim +
         "\nLPIPS: VGG, v0.1 (Zhang et al. 2018), per view; '–' without LPIPS weights.\n"
         "Normals: rendered (alpha-normalised) vs reference camera-space normals where alpha > 0.5 and a "
         "reference exists; L1 = mean |n - n_ref| over the 3 components, cosine = mean n . n_ref (unit vectors); "
         "per scene over its pixels, then the mean over the scenes of all datasets that have normals.\n"
         "Depth SI-log: scale-invariant log depth error (Eigen et al. 2014), sqrt(mean(d^2) - mean(d)^2) with "
         "d = log(rendered depth) - log(reference depth) where alpha > 0.5 and both exist, per view, then the mean "
         "over a scene's views and over the scenes that have reference depth; a global scale of the depth gives 0.\n"
         "Planar roughness (texture leaking into depth): rho(z) = z * (mean of 1/z over the 8 neighbours - 1/z), 0 on "
         "any plane; the mean of |rho(rendered) - rho(reference)| over the pixels whose 3x3 neighbourhood is rendered "
         "(alpha > 0.5) and planar in the reference (|rho| < " + fmt::format("{:g}", kPlanarDepthTolerance) +
         ", and reference normals within " + fmt::format("{:.1f}", std::acos(kPlanarNormalCosine) * 180.0 / std::acos(-1.0)) +
         " degrees of the centre's where they exist), per scene over its pixels, then over the scenes; a render "
         "equal to the reference (or a multiple of it) scores 0, a depth carrying a 1-pixel checkerboard of relative "
         "amplitude e about e.\n";
}

std::string seed_group(const std::string& name) {
  const auto at = name.rfind(" seed ");
  if (at == std::string::npos || at + 6 >= name.size()) return "";
  for (size_t i = at + 6; i < name.size(); ++i)
    if (!std::isdigit(static_cast<unsigned char>(name[i]))) return "";
  return name.substr(0, at);
}

std::string seeds_markdown(const std::vector<EvalResults>& runs) {
  std::vector<std::string> rows;
  std::map<std::string, std::vector<Means>> by_row;
  for (const auto& r : runs) {
    const std::string g = seed_group(r.name);
    if (g.empty()) continue;
    if (!by_row.count(g)) rows.push_back(g);
    by_row[g].push_back(dataset_means(r.scores).back());
  }
  bool any = false;
  for (const auto& [g, ms] : by_row) any = any || ms.size() >= 2;
  if (!any) return "";
  // mean and spread (max - min) of one field over a row's seeds
  auto stat = [](const std::vector<Means>& ms, double Means::*f, int decimals) {
    double lo = INFINITY, hi = -INFINITY, sum = 0;
    int n = 0;
    for (const auto& m : ms)
      if (std::isfinite(m.*f)) {
        lo = std::min(lo, m.*f);
        hi = std::max(hi, m.*f);
        sum += m.*f;
        ++n;
      }
    if (n == 0) return std::string("–");
    return cell(sum / n, decimals) + (n > 1 ? " ± " + cell(hi - lo, decimals) : std::string());
  };
  std::ostringstream os;
  os << "| Row | Seeds | PSNR ↑ | SSIM ↑ | LPIPS ↓ | Normal L1 ↓ | Normal cosine ↑ | Depth SI-log ↓ | Planar roughness ↓ "
        "| mean-colour oracle | dataset mean | swap |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
  for (const auto& g : rows) {
    const auto& ms = by_row[g];
    os << "| " << g << " | " << ms.size() << " | " << stat(ms, &Means::psnr, 2) << " | " << stat(ms, &Means::ssim, 3)
       << " | " << stat(ms, &Means::lpips, 3) << " | " << stat(ms, &Means::normal_l1, 3) << " | "
       << stat(ms, &Means::normal_cosine, 3) << " | " << stat(ms, &Means::depth_si_log, 3) << " | "
       << stat(ms, &Means::planar_roughness, 4) << " | " << stat(ms, &Means::mean_colour_psnr, 2) << " | "
       << stat(ms, &Means::dataset_mean_psnr, 2) << " | " << stat(ms, &Means::swap_psnr, 2) << " |\n";
  }
  os << "\nOver seeds: each cell is the mean over the row's seeds of the per-run mean over all scenes, ± the spread "
        "(largest minus smallest seed). A gap between two rows smaller than their spreads is not told from seed "
        "noise. The last three columns are the baselines' PSNR on the same views (a model ignoring its input "
        "scores about the swap figure).\n";
  return os.str();
}

std::string table1_markdown(const std::vector<EvalResults>& runs) {
  std::vector<std::string> datasets;
  for (const auto& r : runs)
    for (const auto& s : r.scores)
      if (std::find(datasets.begin(), datasets.end(), s.dataset) == datasets.end()) datasets.push_back(s.dataset);
  std::ostringstream os;
  os << "| Method |";
  for (const auto& d : datasets) os << ' ' << d << " PSNR ↑ | " << d << " SSIM ↑ | " << d << " LPIPS ↓ |";
  os << " Geometry L1 ↓ | Geometry Cosine ↑ | Depth SI-log ↓ | Planar roughness ↓ | Scenes |\n|---|";
  for (size_t i = 0; i < datasets.size(); ++i) os << "---:|---:|---:|";
  os << "---:|---:|---:|---:|---:|\n";
  std::vector<std::string> conventions, random_runs;
  for (const auto& r : runs) {
    auto means = dataset_means(r.scores);
    os << "| " << r.name << " |";
    for (const auto& d : datasets) {
      const Means* m = nullptr;
      for (const auto& x : means)
        if (x.dataset == d && !(&x == &means.back())) m = &x;
      if (!m) {
        os << " | | |";
        continue;
      }
      os << ' ' << cell(m->psnr, 2) << " | " << cell(m->ssim, 3) << " | " << cell(m->lpips, 3)
         << " |";
    }
    const auto& all = means.back();
    os << ' ' << cell(all.normal_l1, 3) << " | " << cell(all.normal_cosine, 3) << " | " << cell(all.depth_si_log, 3)
       << " | " << cell(all.planar_roughness, 4) << " | " << all.scenes
       << '/' << (all.scenes + all.failed) << " |\n";
    // The baselines on the same views, PSNR only: what ignoring the input reaches.
    const std::pair<const char*, double Means::*> rows[] = {{"mean-colour oracle", &Means::mean_colour_psnr},
                                                            {"dataset mean (leave-one-out)", &Means::dataset_mean_psnr},
                                                            {"swap (renders vs another scene)", &Means::swap_psnr}};
    for (const auto& [label, field] : rows) {
      bool any = false;
      for (const auto& m : means) any = any || std::isfinite(m.*field);
      if (!any) continue;
      os << "| ↳ " << label << " |";
      for (const auto& d : datasets) {
        const Means* m = nullptr;
        for (const auto& x : means)
          if (x.dataset == d && !(&x == &means.back())) m = &x;
        os << ' ' << (m ? cell(m->*field, 2) : std::string()) << " | | |";
      }
      os << " | | | | |\n";
    }
    if (all.random_latent_scenes > 0) random_runs.push_back(r.name + " (" + std::to_string(all.random_latent_scenes) +
                                                            " of " + std::to_string(all.scenes) + " scenes)");
    if (std::find(conventions.begin(), conventions.end(), r.ssim) == conventions.end()) conventions.push_back(r.ssim);
  }
  os << "\nScenes: scored / attempted; means cover the scored scenes only (failures are listed in each run's "
        "results).\n";
  // What is rendered: flat_infer exports the triangles of the same threshold unless its --prune-opacity says otherwise.
  os << "\nRendered triangles: opacity at or above ";
  for (size_t i = 0; i < runs.size(); ++i)
    os << (i ? "; " : "") << (std::isnan(runs[i].prune_opacity) ? std::string("(not recorded)") : cell(runs[i].prune_opacity, 3))
       << (runs.size() > 1 ? " (" + runs[i].name + ")" : "");
  os << " (the model's pipeline.prune_opacity, as flat_infer exports by default; 0.05 there for a model without "
        "one).\n";
  os << "\nBaselines (↳ rows, PSNR on the same views): the mean-colour oracle paints each view its own mean colour; "
        "the dataset mean predicts every view as the other scenes' mean frame of the same index; swap scores each "
        "scene's renders against the next scene's frames of the same index. A model that ignores its input scores "
        "its own PSNR about equal to swap.\n";
  if (!random_runs.empty()) {
    os << "\n**RANDOM-ENCODER LATENTS: ";
    for (size_t i = 0; i < random_runs.size(); ++i) os << (i ? "; " : "") << random_runs[i];
    os << ". These latents carry almost nothing of the scene; such figures are pipeline checks, not results.**\n";
  }
  if (conventions.size() > 1) os << "\n**Warning: these runs use different SSIM conventions; their SSIM columns do not compare.**\n";
  for (const auto& c : conventions) os << "\n" << metric_definitions(c);
  return os.str();
}

}  // namespace flat::eval
